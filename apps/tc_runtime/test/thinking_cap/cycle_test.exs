defmodule ThinkingCap.CycleTest do
  # One timing worker per node: these tests share it and kill it.
  use ExUnit.Case, async: false

  alias ThinkingCap.Cycle
  import ThinkingCap.Testing.Cycle

  @moduletag :tmp_dir

  setup do
    name = :"act_#{System.unique_integer([:positive])}"
    on_exit(fn -> Cycle.remove(name) end)
    %{name: name}
  end

  test "the worker says whether the OS granted SCHED_FIFO and mlockall" do
    status = Cycle.status()
    assert is_boolean(status.sched_fifo) and is_boolean(status.mlockall)
    assert status.message =~ "SCHED_FIFO"
    # these machines run as root: both are granted (DESIGN.md)
    if System.cmd("id", ["-u"]) == {"0\n", 0}, do: assert(status.sched_fifo and status.mlockall)
  end

  test "bad activity options raise in the caller; the server and other activities carry on",
       %{name: name} do
    :ok = Cycle.add(name, period: 0.01)
    server = Process.whereis(Cycle)

    for bad <- [
          [period: 0],
          [period: :fast],
          [period: 0.01, deadline: 0.02],
          [period: 0.01, priority: 0],
          [period: 0.01, deadline: 0.008, lead: 0.003],
          [period: 0.01, lead: -0.001],
          [period: 0.1, deadline: 0.05, lead: 0.01]
        ] do
      assert_raise ArgumentError, fn -> Cycle.add(:"#{name}_bad", bad) end
    end

    assert Process.whereis(Cycle) == server
    assert %{cycle: _} = release(name)
  end

  test "a name another live process cycles is refused; a dead owner's is taken over", %{
    name: name
  } do
    parent = self()

    owner =
      spawn(fn ->
        send(parent, {:added, Cycle.add(name, period: 0.05)})
        Process.sleep(:infinity)
      end)

    assert_receive {:added, :ok}
    assert {:error, {:name_taken, ^owner}} = Cycle.add(name, period: 0.05)
    ref = Process.monitor(owner)
    Process.exit(owner, :kill)
    assert_receive {:DOWN, ^ref, :process, ^owner, :killed}
    assert :ok = Cycle.add(name, period: 0.05)
    assert %{cycle: _} = release(name)
  end

  test "releases come every period and a result in time is applied fresh", %{name: name} do
    :ok = Cycle.add(name, period: 0.01, deadline: 0.008, priority: 60)
    # a loaded machine may make a result late: answered until one is in time
    {r1, a1} = fresh_result(name, {:vel, 0.2, 0.0}, nil)
    assert %{kind: :fresh, command: {:vel, 0.2, 0.0}} = a1
    assert a1.cycle == r1.cycle
    # when, on the worker's clock: its release plus the response
    assert a1.applied_ns == r1.released_ns + round(a1.response_us * 1000)
    r2 = release_after(name, r1)
    # absolute deadlines: releases are scheduled on the period's grid (a
    # release the worker was too late for is skipped, not shifted)
    gap = r2.scheduled_ns - r1.scheduled_ns
    assert gap > 0 and rem(gap, 10_000_000) == 0
  end

  test "a missed deadline gets the fallback in that cycle; the late result is reported, not applied",
       %{name: name} do
    :ok = Cycle.add(name, period: 0.02, deadline: 0.005, fallback: :stop)
    r = release(name)

    assert %{cycle: cycle, kind: :fallback, command: :stop, response_us: response} =
             fallback = applied(name)

    assert cycle == r.cycle
    assert fallback.applied_ns >= r.scheduled_ns + 5_000_000
    # not before the deadline (measured from the actual release, so less
    # its jitter); how soon after it is the timing benchmark's business
    assert response > 4_000
    Cycle.result(r, {:vel, 1.0, 0.0})
    assert %{kind: :late, command: nil, applied_ns: nil} = applied(name)
  end

  test "a lead releases early; the owner waits for the instant due; the deadline counts from it",
       %{name: name} do
    :ok = Cycle.add(name, period: 0.02, deadline: 0.005, lead: 0.004, fallback: :stop)
    r = release(name)
    # scheduled_ns stays on the period's grid: the instant the release is due
    r2 = release_after(name, r)
    assert rem(r2.scheduled_ns - r.scheduled_ns, 20_000_000) == 0
    :ok = Cycle.await_release(r2)
    assert Cycle.Clock.now_ns() >= r2.scheduled_ns

    # left unanswered: the fallback comes at scheduled_ns + deadline, not
    # at the early release + deadline
    fallback = applied_until(name, &(&1.cycle == r2.cycle))
    assert %{kind: :fallback, command: :stop} = fallback
    assert fallback.applied_ns >= r2.scheduled_ns + 5_000_000

    # released early, unless the machine stalled the worker for the lead
    early = for _ <- 1..5, r = release(name), do: r.released_ns < r.scheduled_ns
    assert Enum.any?(early)
  end

  test "the worker wakes early and spins: a release leaves on its instant, never before",
       %{name: name} do
    assert Cycle.status().message =~ "wakes 100 us early"
    :ok = Cycle.add(name, period: 0.01, deadline: 0.005, fallback: :stop)
    releases = for _ <- 1..20, do: release(name)
    assert Enum.all?(releases, &(&1.released_ns >= &1.scheduled_ns))
    # the thread woke some microseconds after its timer, yet the release
    # left sooner after its instant than that: it woke ahead of the
    # instant (without the early wake-up, a release leaves after its
    # timer's lateness, never before)
    assert Enum.any?(releases, &(&1.released_ns - &1.scheduled_ns < &1.timer_late_ns))
    assert %{^name => %{timer_late_us: %{n: n}}} = Cycle.timing()
    assert n >= 20
  end

  test "the worker refuses a wake-up earlier than 2 ms, and the setting is checked" do
    worker = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")

    assert {text, 2} = System.cmd(worker, ["--wake-early-us", "5000"], stderr_to_stdout: true)

    assert text =~ "--wake-early-us takes 0 to 2000, not 5000"
    assert {text, 2} = System.cmd(worker, ["--wake-early"], stderr_to_stdout: true)
    assert text =~ "unknown argument --wake-early"

    Application.put_env(:tc_runtime, :wake_early_us, 2500)

    try do
      assert_raise ArgumentError, ~r/wake_early_us must be an integer from 0 to 2000/, fn ->
        ThinkingCap.Cycle.Core.Worker.wake_early_us()
      end
    after
      Application.delete_env(:tc_runtime, :wake_early_us)
    end
  end

  # Counts, not times: on a loaded machine any answer may be late and the
  # worker may skip releases it was too late for; what is counted must
  # add up whatever the timing was.
  test "statistics count cycles, fallbacks and late results", %{name: name} do
    :ok = Cycle.add(name, period: 0.005, deadline: 0.004)

    # every other release answered, the others left to their fallback
    answered =
      Enum.flat_map(1..20, fn i ->
        r = release(name)

        if rem(i, 2) == 0 do
          Cycle.result(r, :go)
          [r.cycle]
        else
          []
        end
      end)

    # each answer is reported, applied fresh or late (after its fallback)
    reports =
      for cycle <- answered,
          do: applied_until(name, &(&1.cycle == cycle and &1.kind in [:fresh, :late])).kind

    late = Enum.count(reports, &(&1 == :late))
    stats = Cycle.timing()[name]
    assert stats.cycles >= 20
    assert stats.response_us.n + stats.late >= 10
    assert stats.late >= late
    # the 10 left unanswered, and every late one, got their fallback
    assert stats.fallbacks >= 10 + late
    assert stats.jitter_us.n == stats.cycles
    # cycle times are whole periods (absolute deadlines), more than one
    # only where releases were skipped
    assert stats.cycle_us.n == stats.cycles - 1
    assert stats.cycle_us.min >= 5000.0

    assert_in_delta stats.cycle_us.mean * stats.cycle_us.n,
                    5000.0 * (stats.cycle_us.n + stats.skipped),
                    1.0
  end

  test "the statistics live in a process of their own: killed, it comes back, the cycle unmoved",
       %{name: name} do
    :ok = Cycle.add(name, period: 0.01, deadline: 0.005)
    for _ <- 1..5, do: name |> release() |> Cycle.result(:go)
    cycle = Process.whereis(Cycle)
    stats = Process.whereis(ThinkingCap.Cycle.Core.Statistics)
    assert is_pid(stats) and stats != cycle
    assert Cycle.timing()[name].cycles >= 5

    Process.exit(stats, :kill)

    ThinkingCap.Testing.Cluster.wait_until(fn ->
      pid = Process.whereis(ThinkingCap.Cycle.Core.Statistics)
      pid != nil and pid != stats
    end)

    assert Process.whereis(Cycle) == cycle
    # the new keeper was told of the activity: its releases are counted
    for _ <- 1..3, do: name |> release() |> Cycle.result(:go)
    assert Cycle.timing()[name].cycles >= 3
  end

  test "a keeper left behind queues a bounded number of samples; the rest are counted dropped",
       %{name: name} do
    alias ThinkingCap.Cycle.Core.Statistics
    :ok = Cycle.add(name, period: 0.01, deadline: 0.005)
    keeper = Process.whereis(Statistics)
    before = Statistics.max_backlog(200)
    on_exit(fn -> Statistics.max_backlog(before) end)
    dropped = Cycle.status().statistics_dropped

    # the keeper stalled (as on a node whose schedulers other work
    # keeps busy) while the cycle and the hosts keep sending
    :ok = :sys.suspend(keeper)
    for _ <- 1..10, do: name |> release() |> Cycle.result(:go)
    for i <- 1..1_000, do: Statistics.cpu(0, i)
    {:message_queue_len, queued} = Process.info(keeper, :message_queue_len)
    :ok = :sys.resume(keeper)

    # at most the bound queued (activities added and removed pass too)
    assert queued <= 200 + 5
    assert Cycle.status().statistics_dropped - dropped >= 1_000 - 200

    # the keeper takes its queue and counts on
    Statistics.max_backlog(before)
    for _ <- 1..3, do: name |> release() |> Cycle.result(:go)
    assert Cycle.timing()[name].cycles >= 3
  end

  test "a killed worker is restarted; its activities stay stopped until a fresh command", %{
    name: name
  } do
    :ok = Cycle.add(name, period: 0.01, fallback: :stop)
    assert {_, %{kind: :fresh}} = fresh_result(name, :go, nil)
    restarts = Cycle.status().restarts

    {_, 0} = System.cmd("kill", ["-9", "#{Cycle.worker_os_pid()}"])

    # the subscribers hear that the fallback holds (the restart's own
    # report, cycle 0, not a deadline missed before the kill), then
    # releases resume; no worker applied it, so there is no worker time
    assert %{kind: :fallback, command: :stop, applied_ns: nil} =
             applied_until(name, &(&1.kind == :fallback and &1.cycle == 0))

    assert Cycle.status().restarts == restarts + 1
    # releases resume: answered (the old worker's releases still queued
    # here are late for the new one) until one is applied fresh
    assert {_, %{kind: :fresh, command: :go_again}} = fresh_result(name, :go_again, nil)
  end

  describe "the release boost" do
    @root System.cmd("id", ["-u"]) == {"0\n", 0}

    # {scheduler priorities, poller priority}
    defp priorities do
      policies = ThinkingCap.Runtime.Scheduling.policies()
      {pollers, schedulers} = Enum.split_with(policies, fn {n, _} -> n =~ "_poller" end)
      priority = fn threads -> threads |> Enum.map(&elem(&1, 1).rt_priority) |> Enum.uniq() end
      {priority.(schedulers), priority.(pollers)}
    end

    # other tests' activities may be pending a moment: the boost ends then
    defp unboosted do
      try do
        ThinkingCap.Testing.Cluster.wait_until(fn -> priorities() == {[1], [2]} end, 5000)
      rescue
        RuntimeError -> :not_in_time
      end

      priorities()
    end

    test "while a result is pending the BEAM's schedulers (dirty CPU too) run at 20 and its poller at 21",
         %{name: name} do
      if @root do
        assert unboosted() == {[1], [2]}
        :ok = Cycle.add(name, period: 1.0)
        r = release(name)
        assert priorities() == {[20], [21]}
        Cycle.result(r, :go)
        assert %{kind: :fresh} = applied(name)
        assert unboosted() == {[1], [2]}
      else
        assert ThinkingCap.Runtime.Scheduling.release_boost() == []
      end
    end

    test "a missed deadline ends the boost with the fallback", %{name: name} do
      if @root do
        :ok = Cycle.add(name, period: 1.0, deadline: 0.05)
        _r = release(name)
        assert %{kind: :fallback} = applied(name)
        assert unboosted() == {[1], [2]}
      end
    end

    test "a worker killed during a boost: the threads are put back before the next one starts",
         %{name: name} do
      if @root do
        :ok = Cycle.add(name, period: 1.0)
        _r = release(name)
        assert priorities() == {[20], [21]}
        restarts = Cycle.status().restarts
        {_, 0} = System.cmd("kill", ["-9", "#{Cycle.worker_os_pid()}"])
        assert %{kind: :fallback, cycle: 0} = applied_until(name, &(&1.cycle == 0))
        # (a call: answered once the restart is done)
        assert Cycle.status().restarts == restarts + 1
        # the new worker's first release is a second away
        assert priorities() == {[1], [2]}
      end
    end
  end

  test "when the BEAM side closes, the worker applies every fallback and exits", %{tmp_dir: dir} do
    out = Path.join(dir, "out.bin")
    worker = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")
    # :eof keeps the port open although the worker's output goes to the file
    port = Port.open({:spawn, "sh -c 'exec #{worker} > #{out}'"}, [:binary, {:packet, 4}, :eof])
    {:os_pid, os_pid} = Port.info(port, :os_pid)
    stop = :erlang.term_to_binary(:stop)
    Port.command(port, <<?A, 7::16, 1_000_000_000::64, 500_000_000::64, 50, stop::binary>>)
    Process.sleep(100)
    Port.close(port)

    ThinkingCap.Testing.Cluster.wait_until(fn -> not File.exists?("/proc/#{os_pid}") end, 5000)
    frames = parse_frames(File.read!(out))
    assert [<<?H, _::binary>> | _] = frames
    assert <<?P, 7::16, _cycle::32, 1, 0, _response::64, ^stop::binary>> = List.last(frames)
  end

  test "bad frames are refused with an error and the worker keeps running", %{name: name} do
    port = :persistent_term.get({Cycle, :port})

    ExUnit.CaptureLog.capture_log(fn ->
      Port.command(port, <<?Z, 1, 2, 3>>)
      Port.command(port, <<?A, 1>>)
      Port.command(port, <<?C>>)
      Process.sleep(50)
    end) =~ "refused a frame"

    # a long period: the result is in time even on a loaded machine
    :ok = Cycle.add(name, period: 0.2)
    Cycle.result(release(name), :still_fine)
    assert %{kind: :fresh, command: :still_fine} = applied(name)
  end

  describe "a wire (a FIFO read by cat stands for the serial line)" do
    test "fresh results' bytes go on the wire in order", %{name: name, tmp_dir: dir} do
      {fifo, reader} = fifo(dir)
      :ok = Cycle.add(name, period: 0.05, deadline: 0.04)
      :ok = attach(name, fifo)

      for i <- 1..5 do
        assert %{kind: :fresh, wired: true, command: {:n, ^i}} = fresh(name, {:n, i}, "go #{i}\n")
      end

      wire = wire_until(reader, &String.contains?(&1, "go 5\n"))
      # fallbacks applied while a result was late may come between; the fresh ones in order
      assert wire |> String.split("\n", trim: true) |> Enum.reject(&(&1 == "stop")) ==
               for(i <- 1..5, do: "go #{i}")
    end

    test "a missed deadline puts the fallback bytes on the wire in that cycle, the late bytes never",
         %{name: name, tmp_dir: dir} do
      {fifo, reader} = fifo(dir)
      :ok = Cycle.add(name, period: 0.05, deadline: 0.01)
      :ok = attach(name, fifo)
      r = release_after(name, fresh_release(name, :go, "go\n"))

      # not answered: its fallback, on the wire, then the late result
      assert %{kind: :fallback, wired: true, command: :stop} =
               applied_until(name, &(&1.cycle == r.cycle))

      Cycle.result(r, :late, "late\n")
      assert %{kind: :late, wired: false} = applied_until(name, &(&1.kind == :late))
      :ok = Cycle.remove(name)

      wire = wire_until(reader, &String.contains?(&1, "go\nstop\n"))
      [_, after_go] = String.split(wire, "go\n")
      assert String.starts_with?(after_go, "stop\n")
      refute wire_until(reader, &(&1 =~ ~r/late|go\nstop\n(stop\n)+$/), wire, 300) =~ "late"
    end

    test "removing the activity puts its fallback bytes on the wire", %{name: name, tmp_dir: dir} do
      {fifo, reader} = fifo(dir)
      # a long period: no deadline passes before the removal
      :ok = Cycle.add(name, period: 1.0, deadline: 0.9)
      :ok = attach(name, fifo, "STOP!")
      fresh_release(name, :go, "go;")
      wire = wire_until(reader, &String.ends_with?(&1, "go;"))
      assert wire =~ ~r/^(STOP!)*go;$/

      :ok = Cycle.remove(name)
      # the removal's own report says the fallback went on the wire
      assert %{kind: :fallback, cycle: 0, wired: true} = applied_until(name, &(&1.cycle == 0))

      assert wire_until(reader, &String.ends_with?(&1, "go;STOP!"), wire) =~
               ~r/^(STOP!)*go;STOP!$/
    end

    test "a bad device or fallback is refused with an error naming it", %{
      name: name,
      tmp_dir: dir
    } do
      :ok = Cycle.add(name, period: 0.05)
      missing = Path.join(dir, "no/such/tty")
      assert {:error, message} = Cycle.attach_wire(name, missing, "stop")
      assert message =~ missing and message =~ "No such file or directory"

      assert {:error, message} = Cycle.attach_wire(name, dir, "stop")
      assert message =~ dir and message =~ "Is a directory"

      assert {:error, message} = Cycle.attach_wire(:no_such_activity, missing, "stop")
      assert message =~ ":no_such_activity"
      assert {:error, message} = Cycle.attach_wire(name, "", "stop")
      assert message =~ "path"
      assert {:error, message} = Cycle.attach_wire(name, "/dev/null", [:not_bytes])
      assert message =~ "/dev/null" and message =~ "iodata"
      assert {:error, _} = Cycle.attach_wire(name, "/dev/null", :binary.copy("x", 5000))

      # without a wire the activity runs as before
      assert %{kind: :fresh, wired: false} = fresh(name, :go, "go\n")

      # wire bytes that are not bytes: nothing sent, the fallback applies
      assert ExUnit.CaptureLog.capture_log(fn ->
               r = newest(name, release(name))
               assert :ok = Cycle.result(r, :go, [:not_bytes])
               assert %{kind: :fallback} = applied_until(name, &(&1.cycle == r.cycle))
             end) =~ "not iodata"

      assert %{wire: nil, wire_errors: 0} = Cycle.timing()[name]
    end

    test "a killed worker is restarted with the wire attached again", %{name: name, tmp_dir: dir} do
      {fifo, reader} = fifo(dir)
      :ok = Cycle.add(name, period: 0.05)
      :ok = attach(name, fifo)
      fresh(name, :before, "before\n")
      wire_until(reader, &String.contains?(&1, "before\n"))

      {_, 0} = System.cmd("kill", ["-9", "#{Cycle.worker_os_pid()}"])
      # the restart's own report: the new worker wrote nothing yet
      assert %{kind: :fallback, wired: false} = applied_until(name, &(&1.cycle == 0))

      assert %{kind: :fresh, wired: true} = fresh(name, :after, "after\n")
      assert wire_until(reader, &String.contains?(&1, "after\n")) =~ ~r/^(stop\n)*after\n/
      assert Cycle.timing()[name].wire == fifo
    end

    test "a line that went away is reported and reopened by the worker", %{
      name: name,
      tmp_dir: dir
    } do
      {fifo, reader} = fifo(dir)
      :ok = Cycle.add(name, period: 0.02)
      :ok = attach(name, fifo)
      # nobody answers: the fallback bytes every cycle
      wire_until(reader, &String.contains?(&1, "stop\n"))

      ExUnit.CaptureLog.capture_log(fn ->
        # the reader gone: writes fail (EPIPE), the worker closes the line
        {:os_pid, os_pid} = Port.info(reader, :os_pid)
        {_, 0} = System.cmd("kill", ["-9", "#{os_pid}"])

        ThinkingCap.Testing.Cluster.wait_until(
          fn -> Cycle.timing()[name].wire_errors >= 1 end,
          5000
        )

        # a new reader: the worker opens the line again by itself
        reader = cat(fifo)
        assert wire_until(reader, &String.contains?(&1, "stop\n")) =~ "stop\n"
      end)
    end

    # A wire's path that names another device after its line went away
    # (a later test's pty that got the same /dev/pts/N, a symlink pointed
    # elsewhere) is someone else's: the worker must not write there.
    test "a line gone whose path names another device now is not reopened until attached again",
         %{name: name, tmp_dir: dir} do
      {fifo, reader} = fifo(dir)
      link = Path.join(dir, "by-id")
      :ok = File.ln_s(fifo, link)
      :ok = Cycle.add(name, period: 0.02)
      :ok = attach(name, link)
      wire_until(reader, &String.contains?(&1, "stop\n"))

      log =
        ExUnit.CaptureLog.capture_log(fn ->
          {:os_pid, os_pid} = Port.info(reader, :os_pid)
          {_, 0} = System.cmd("kill", ["-9", "#{os_pid}"])

          ThinkingCap.Testing.Cluster.wait_until(
            fn -> Cycle.timing()[name].wire_errors >= 1 end,
            5000
          )

          # the link now names another line, with its own reader
          other = Path.join(dir, "other")
          {_, 0} = System.cmd("mkfifo", [other])
          other_reader = cat(other)
          File.rm!(link)
          :ok = File.ln_s(other, link)

          ThinkingCap.Testing.Cluster.wait_until(
            fn -> Cycle.timing()[name].wire_errors >= 2 end,
            5000
          )

          # a second of fallbacks: none of them on the other line
          assert wire_until(other_reader, &(&1 != ""), "", 999) == ""

          # its owner hands the new device over: written to from then on
          :ok = attach(name, link)
          assert wire_until(other_reader, &String.contains?(&1, "stop\n")) =~ "stop\n"
        end)

      assert log =~ "the path names another device now"
    end

    test "when the BEAM side closes, the worker writes the fallback bytes on the wire", %{
      tmp_dir: dir
    } do
      {fifo, reader} = fifo(dir)
      out = Path.join(dir, "out.bin")
      worker = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")

      port =
        Port.open({:spawn_executable, "/bin/sh"}, [
          :binary,
          {:packet, 4},
          :eof,
          args: ["-c", ~s(exec "$0" > "$1"), worker, out]
        ])

      {:os_pid, os_pid} = Port.info(port, :os_pid)
      stop = :erlang.term_to_binary(:stop)
      Port.command(port, <<?A, 7::16, 1_000_000_000::64, 500_000_000::64, 50, stop::binary>>)
      Port.command(port, <<?W, 7::16, 5::16, "halt\n", fifo::binary>>)
      Process.sleep(100)
      Port.close(port)

      assert wire_until(reader, &(&1 == "halt\n")) == "halt\n"
      ThinkingCap.Testing.Cluster.wait_until(fn -> not File.exists?("/proc/#{os_pid}") end, 5000)
      frames = parse_frames(File.read!(out))
      assert <<?V, 7::16, 1, "attached ", _::binary>> = Enum.at(frames, 1)
      assert <<?P, 7::16, _cycle::32, 1, 1, _response::64, ^stop::binary>> = List.last(frames)
    end

    test "bad wire frames are refused and the worker keeps running", %{name: name} do
      port = :persistent_term.get({Cycle, :port})

      ExUnit.CaptureLog.capture_log(fn ->
        Port.command(port, <<?W, 1>>)
        Port.command(port, <<?W, 0, 1, 200::16, "short">>)
        Port.command(port, <<?W, 0, 1, 0::16, "/dev/", 0, "null">>)
        Port.command(port, <<?D, 0, 1, 0, 0, 0, 1, 9000::16>>)
        Port.command(port, <<?X>>)
        Process.sleep(50)
      end)

      :ok = Cycle.add(name, period: 0.2)
      assert %{kind: :fresh, command: :still_fine} = fresh(name, :still_fine, "x")
    end
  end

  ## Wire helpers

  # a FIFO in dir and a reader of it
  defp fifo(dir) do
    path = Path.join(dir, "line")
    {_, 0} = System.cmd("mkfifo", [path])
    {path, cat(path)}
  end

  # cat opens the FIFO read-write: never an end of file when a writer closes
  defp cat(path) do
    port =
      Port.open({:spawn_executable, "/bin/sh"}, [
        :binary,
        :stream,
        args: ["-c", ~s(exec cat 0<>"$0" 2>/dev/null), path]
      ])

    {:os_pid, os_pid} = Port.info(port, :os_pid)
    on_exit(fn -> System.cmd("kill", ["-9", "#{os_pid}"], stderr_to_stdout: true) end)
    # the line has its reader once cat holds it open: a worker that opens
    # it before then is refused (ENXIO), as by a line with nobody on it
    ThinkingCap.Testing.Cluster.wait_until(fn -> holds?(os_pid, path) end, 5000)
    port
  end

  defp holds?(os_pid, path) do
    fds = "/proc/#{os_pid}/fd"

    case File.ls(fds) do
      {:ok, names} -> Enum.any?(names, &(File.read_link(Path.join(fds, &1)) == {:ok, path}))
      {:error, _} -> false
    end
  end

  # until cat has the FIFO open, opening it for writing fails (ENXIO)
  defp attach(name, fifo, fallback \\ "stop\n") do
    ThinkingCap.Testing.Cluster.wait_until(
      fn -> Cycle.attach_wire(name, fifo, fallback) == :ok end,
      5000
    )
  end

  # answers releases until one is applied fresh (`bytes` for the wire, or nil)
  defp fresh(name, command, bytes), do: name |> fresh_result(command, bytes) |> elem(1)
  defp fresh_release(name, command, bytes), do: name |> fresh_result(command, bytes) |> elem(0)

  defp fresh_result(name, command, bytes, tries \\ 20) do
    if tries == 0, do: flunk("no result of #{inspect(name)} was applied fresh")
    r = newest(name, release(name))
    if bytes, do: Cycle.result(r, command, bytes), else: Cycle.result(r, command)

    # the result's own report: fresh, or late (a late one says its cycle);
    # none when it went to a worker that died meanwhile: answered again
    case report(name, r.cycle, System.monotonic_time(:millisecond) + 1000) do
      %{kind: :fresh} = event -> {r, event}
      _late_or_lost -> fresh_result(name, command, bytes, tries - 1)
    end
  end

  defp report(name, cycle, deadline) do
    receive do
      {:tc_cycle, :applied, ^name, %{cycle: ^cycle, kind: kind} = event} when kind != :fallback ->
        event

      {:tc_cycle, :applied, ^name, _other} ->
        report(name, cycle, deadline)
    after
      max(deadline - System.monotonic_time(:millisecond), 0) -> nil
    end
  end

  # releases queued up behind a slow test are stale: the newest one
  defp newest(name, r) do
    receive do
      {:tc_cycle, :release, ^name, newer} -> newest(name, newer)
    after
      0 -> r
    end
  end

  # the release after r
  defp release_after(name, r) do
    case release(name) do
      %{cycle: c} = next when c > r.cycle -> next
      _ -> release_after(name, r)
    end
  end

  defp wire_until(reader, fun, acc \\ "", timeout \\ 5000) do
    if fun.(acc) do
      acc
    else
      receive do
        {^reader, {:data, data}} -> wire_until(reader, fun, acc <> data, timeout)
      after
        timeout -> if timeout < 1000, do: acc, else: flunk("the wire got only #{inspect(acc)}")
      end
    end
  end

  defp parse_frames(<<len::32, frame::binary-size(len), rest::binary>>),
    do: [frame | parse_frames(rest)]

  defp parse_frames(<<>>), do: []
end
