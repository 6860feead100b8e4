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

  test "releases come every period and a result in time is applied fresh", %{name: name} do
    :ok = Cycle.add(name, period: 0.01, deadline: 0.008, priority: 60)
    r1 = release(name)
    :ok = Cycle.result(r1, {:vel, 0.2, 0.0})
    assert %{cycle: c1, kind: :fresh, command: {:vel, 0.2, 0.0}} = applied(name)
    assert c1 == r1.cycle
    r2 = release(name)
    assert r2.cycle == r1.cycle + 1
    # absolute deadlines: releases are scheduled exactly one period apart
    assert r2.scheduled_ns - r1.scheduled_ns == 10_000_000
  end

  test "a missed deadline gets the fallback in that cycle; the late result is reported, not applied",
       %{name: name} do
    :ok = Cycle.add(name, period: 0.02, deadline: 0.005, fallback: :stop)
    r = release(name)
    assert %{cycle: cycle, kind: :fallback, command: :stop, response_us: response} = applied(name)
    assert cycle == r.cycle
    # applied at the deadline (measured from the actual release, so less its
    # jitter), not a cycle later
    assert response > 4_000 and response < 15_000
    Cycle.result(r, {:vel, 1.0, 0.0})
    assert %{kind: :late, command: nil} = applied(name)
  end

  test "statistics count cycles, fallbacks and late results", %{name: name} do
    :ok = Cycle.add(name, period: 0.005, deadline: 0.004)

    for i <- 1..20 do
      r = release(name)
      # answer every other release
      if rem(i, 2) == 0, do: Cycle.result(r, :go)
      applied(name)
    end

    stats = Cycle.timing()[name]
    assert stats.cycles >= 20
    assert stats.fallbacks >= 10
    assert stats.response_us.n >= 10
    assert stats.jitter_us.n == stats.cycles
    assert_in_delta stats.cycle_us.mean, 5000, 1000
  end

  test "a killed worker is restarted; its activities stay stopped until a fresh command", %{
    name: name
  } do
    :ok = Cycle.add(name, period: 0.01, fallback: :stop)
    Cycle.result(release(name), :go)
    assert %{kind: :fresh} = applied(name)
    restarts = Cycle.status().restarts

    {_, 0} = System.cmd("kill", ["-9", "#{Cycle.worker_os_pid()}"])

    # the subscribers hear that the fallback holds (the restart's own
    # report, cycle 0, not a deadline missed before the kill), then
    # releases resume
    assert %{kind: :fallback, command: :stop} =
             applied_until(name, &(&1.kind == :fallback and &1.cycle == 0))

    assert Cycle.status().restarts == restarts + 1
    Cycle.result(release(name), :go_again)
    assert %{kind: :fresh, command: :go_again} = applied_until(name, &(&1.kind == :fresh))
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

  defp parse_frames(<<len::32, frame::binary-size(len), rest::binary>>),
    do: [frame | parse_frames(rest)]

  defp parse_frames(<<>>), do: []
end
