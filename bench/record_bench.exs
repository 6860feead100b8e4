Code.require_file("support/nav_run.exs", __DIR__)

defmodule ThinkingCap.Bench.Record do
  @moduledoc """
  `mix tc.bench record [--robots N] [--seconds S] [--step T] [--speed X]
  [--keep]`: N simulated
  robots (default 100), each with its own modules, all recorded by the
  black box's recorder, against the same run without recording; then one
  robot's recording replayed. `--keep` leaves the recordings (their
  directory is printed).

  ## The fleet

  nav2's warehouse map (30 m × 50 m) with reflective beacons spread over
  its free space (one per 25 m²), one real-time simulation
  (`ThinkingCap.Sim`, step T, default 0.02 s) shared by every robot, at
  X simulated seconds per wall second (default 1.0).
  Each robot is an ADF of its own (the office robot's RDF: 8 sonars and
  a 181-beam laser at 10 Hz, beacons at 5 Hz, odometry at 50 Hz), with
  the modules a robot runs:

    * `base_I`: the simulated base (`ThinkingCap.Sim.Robot`), periodic,
      period T / X, deadline 3 ms;
    * `perception_I`: `ThinkingCap.Perception.Fuser`, the Local
      Perceptual Space;
    * `localization_I`: `ThinkingCap.Navigation.Localizer`, the EKF on
      the beacons: the pose estimate;
    * `control_I`: `ThinkingCap.Control.Blender` (avoid, go to, follow a
      wall), the control cycle: periodic 0.1 s / X, deadline 50 ms.

  Each robot is given a goal across the warehouse (a plan tuple, as a
  fleet manager would) and a new one when it gets there. No black box
  (ring buffer), no dashboard.

  ## The runs

  The same fleet (same starts, goals and seeds) for S simulated seconds
  (default 60), twice: without recording, then with every robot
  recorded (`record: [enabled: true]` in its ADF: zstd, chunks every
  simulated second (`chunk_seconds` 1 / X: a chunk holds what it would
  on a robot in real time, so that the bytes and the CPU per tuple do
  not depend on X), the modules traced for replay). Then robot 1's recording is
  replayed (`ThinkingCap.BlackBox.Replay.compare/3`, every traced module).

  ## The figures

  Per simulated second (at X = 1, per wall second): what the fleet
  needs when it runs in real time. 100 robots with their modules need
  about 2.6 cores in real time, more than the 2 of the machine the
  README's figures come from: they run at X = 0.25 there, every robot
  doing a quarter of a second's work each wall second; a recorder's
  work per simulated second does not depend on X, so the figures say
  what recording a real-time fleet costs.

    * `msgs_per_s`: MCAP messages the recorders wrote per second (all
      robots): Foxglove's JSON, the tuples whole (ETF) and the trace
      batches (the tuples recorded are printed too);
    * `mb_per_min`: MB (10^6 B) the recorders wrote per minute, all
      robots (the files' sizes at the end of the window minus at its
      start); a robot's share is this over N, and the days a 64 GB card
      holds are printed;
    * `cpu_pct`: the recorder processes' CPU time per simulated second,
      in per cent of one core. Measured per process: the recorders are traced
      for scheduling (`:erlang.trace/3`, `running`) with the node's
      `cpu_timestamp` flag, so that each schedule-in and schedule-out is
      stamped with the scheduler thread's own CPU time
      (`CLOCK_THREAD_CPUTIME_ID`); a recorder's CPU is the sum of its
      out-minus-in. It covers all a recorder does (its JSON, ETF,
      compression, file writes, its garbage collection) and nothing of
      other processes. The node's batch sender
      (`ThinkingCap.Blackboard.Core.Batches`, which sends the recorders
      their tuples in lists) is traced as the recorders are and printed on
      a line of its own, with the sum. The rest of the cost the recording
      adds elsewhere (the blackboard's delivery to its subscription, the
      modules' hosts hashing what they are delivered for the trace) is in
      `vm_cpu_pct`: the whole VM's CPU time (`/proc/self/stat`) per simulated second
      with recording minus without, less steady on a shared machine.
      The tracing costs the recorders a little at each schedule (the
      thread's CPU clock is read in a system call, 7.8 µs on the machine
      of the README's figures, and a trace message sent): the bench
      measures one traced schedule of a process that does nothing (it
      answers pings) and prints the recorders' CPU less that much a
      schedule beside the figure. The recorders are traced for their
      garbage collections too, on the same clock: the part of their
      CPU the collections took, and how many, are printed;
    * `misses_added`: the deadline misses (fallbacks applied by the timing
      worker) of every robot's control cycle (`control_I`) during the
      recorded run, minus those during the run without; the bases'
      misses are printed too;
    * `replay_equal_pct`: the share of robot 1's module outputs that
      replayed equal.

  If the machine cannot keep up even so, the simulation lags (`lagged`
  steps are printed): its time then runs slower still, and S simulated
  seconds take longer.
  """

  alias ThinkingCap.{BlackBox, Blackboard, Config, Cycle, Runtime, Sim, Tuples}
  alias ThinkingCap.BlackBox.Replay
  alias ThinkingCap.Bench.{Cyclictest, NavRun, ProcStat}
  require Tuples

  # a schedule or a collection this long is reported (OTP's system monitor)
  @hog_ms 5

  @root Path.expand("..", __DIR__)
  @rdf Path.join(@root, "priv/examples/office_robot.rdf")
  @map Path.join(@root, "priv/maps/warehouse.yaml")

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args,
        strict: [robots: :integer, seconds: :float, step: :float, speed: :float, keep: :boolean]
      )

    n = opts[:robots] || 100
    seconds = opts[:seconds] || 60.0
    step = opts[:step] || 0.02
    speed = opts[:speed] || 1.0
    dir = Path.join(System.tmp_dir!(), "tc_record_bench_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)

    try do
      wdf = NavRun.write_wdf(dir, "warehouse_beacons", @map)
      {:ok, world} = Sim.World.load(wdf)
      {starts, goals} = places(world, n)

      IO.puts(
        "record: #{n} robots in #{world.name} (#{length(world.wdf.beacons)} beacons), " <>
          "#{seconds} simulated s each run, sim step #{step} s, " <>
          "#{System.schedulers_online()} schedulers; load #{load()}"
      )

      fleet = %{n: n, wdf: wdf, starts: starts, goals: goals, step: step, speed: speed, dir: dir}
      plain = phase(fleet, seconds, false)
      report("without recording", plain)
      rec = phase(fleet, seconds, true)
      report("recorded", rec)

      {replay_pct, replay_text} = replay(rec.files[robot(1)])
      IO.puts("  replay of #{robot(1)}: #{replay_text}")
      idle_us = traced_idle_schedule_us()

      # per simulated second: what the fleet needs at real time
      sim_s = rec.sim_seconds
      msgs_per_s = rec.messages / sim_s
      mb_per_min = rec.bytes / 1.0e6 / (sim_s / 60)
      cpu_pct = 100 * rec.recorder_cpu_us / (sim_s * 1.0e6)

      vm_pct =
        100 * (rec.vm_cpu_ms / rec.sim_seconds - plain.vm_cpu_ms / plain.sim_seconds) / 1000

      week_gb = mb_per_min / n * 60 * 24 * 7 / 1000

      IO.puts(
        "  per robot: #{fmt(msgs_per_s / n, 1)} messages/s, #{fmt(mb_per_min / n, 2)} MB/min, " <>
          "a week in #{fmt(week_gb, 1)} GB (64 GB card: #{fmt(64 / week_gb * 7, 1)} days); " <>
          "recorders #{fmt(rec.recorder_cpu_us / max(rec.tuples, 1), 1)} µs CPU per tuple " <>
          "(scheduled #{fmt(rec.recorder_runs / max(rec.tuples, 1), 2)} times a tuple, " <>
          "#{fmt(rec.recorder_cpu_us / max(rec.recorder_runs, 1), 1)} µs a time; " <>
          "garbage collection #{fmt(rec.recorder_gc_us / max(rec.tuples, 1), 1)} µs a tuple, " <>
          "#{rec.recorder_gcs} collections of #{fmt(rec.recorder_gc_us / max(rec.recorder_gcs, 1), 0)} µs; " <>
          "longest schedules (µs, those of 1 ms or more, where): " <>
          "#{Enum.map_join(rec.recorder_longest, ", ", &inspect/1)}); " <>
          "dropped #{rec.dropped}; vm_cpu_pct #{fmt(vm_pct, 1)}; load #{load()}"
      )

      IO.puts(
        "  the blackboard's batch sender (the recorders' lists): " <>
          "#{fmt(rec.sender_cpu_us / max(rec.tuples, 1), 1)} µs CPU per tuple, " <>
          "cpu_pct #{fmt(100 * rec.sender_cpu_us / (sim_s * 1.0e6), 1)}; with the recorders' " <>
          "#{fmt(100 * (rec.recorder_cpu_us + rec.sender_cpu_us) / (sim_s * 1.0e6), 1)}"
      )

      # what the measurement itself costs the recorders (see the moduledoc)
      net_us = max(rec.recorder_cpu_us - rec.recorder_runs * idle_us, 0)

      IO.puts(
        "  a traced schedule of an idle process: #{fmt(idle_us, 1)} µs; the recorders less " <>
          "that a time: #{fmt(net_us / max(rec.tuples, 1), 1)} µs per tuple, " <>
          "cpu_pct #{fmt(100 * net_us / (sim_s * 1.0e6), 1)}"
      )

      IO.puts(
        "record: robots=#{n} msgs_per_s=#{round(msgs_per_s)} mb_per_min=#{fmt(mb_per_min, 1)} " <>
          "cpu_pct=#{fmt(cpu_pct, 1)} misses_added=#{max(rec.control_misses - plain.control_misses, 0)} " <>
          "replay_equal_pct=#{fmt(replay_pct, 1)}"
      )
    after
      if opts[:keep], do: IO.puts("  kept #{dir}"), else: File.rm_rf!(dir)
    end
  end

  defp report(label, r) do
    IO.puts(
      "  #{label}: #{fmt(r.wall, 1)} s wall for #{fmt(r.sim_seconds, 1)} simulated s " <>
        "(sim lagged #{r.lagged} steps), control misses #{r.control_misses} of #{r.control_cycles} cycles, " <>
        "base misses #{r.base_misses} of #{r.base_cycles}, VM CPU #{fmt(r.vm_cpu_ms / r.wall / 10, 1)} % of a core" <>
        if(r.record?,
          do:
            "; #{r.tuples} tuples, #{r.messages} messages, #{fmt(r.bytes / 1.0e6, 1)} MB, " <>
              "recorders #{fmt(r.recorder_cpu_us / 1.0e6, 2)} s CPU",
          else: ""
        )
    )

    tails =
      Enum.map_join(r.control_tails, "; ", fn {key, counts} ->
        "#{key} " <>
          if(counts == [],
            do: "none",
            else:
              Enum.map_join(counts, ", ", fn {b, n} ->
                "#{n} of #{div(2 ** (b - 1), 1000)}+ ms"
              end)
          )
      end)

    IO.puts("    control cycles of 8 ms and more: #{tails}")

    IO.puts(
      "    cyclictest in the same window: max #{r.machine.max} µs, p99 #{r.machine.p99} µs, " <>
        "wake-ups 10 ms late or more #{r.machine.over}"
    )

    hogs =
      r.hogs
      |> Enum.sort_by(fn {_, {n, _}} -> -n end)
      |> Enum.take(6)
      |> Enum.map_join(", ", fn {{kind, who, where}, {n, max}} ->
        "#{n} #{kind} of #{who} (#{inspect(where)}, longest #{max} ms)"
      end)

    IO.puts(
      "    schedules and collections of #{@hog_ms} ms or more (system monitor): #{if hogs == "", do: "none", else: hogs}"
    )
  end

  defp robot(i), do: :"rb#{i}"

  # one run of the fleet for `seconds` of simulated time
  defp phase(fleet, seconds, record?) do
    rec_dir = Path.join(fleet.dir, if(record?, do: "rec", else: "plain"))
    File.mkdir_p!(rec_dir)

    adfs =
      for i <- 1..fleet.n do
        path = Path.join(rec_dir, "#{robot(i)}.adf")
        File.write!(path, adf(fleet, i, record?, rec_dir))
        {:ok, adf} = Config.adf(path)
        adf
      end

    try do
      for {adf, i} <- Enum.with_index(adfs, 1) do
        case Runtime.start(adf) do
          {:ok, _} -> :ok
          {:error, failed} -> Mix.raise("#{robot(i)} did not start: #{inspect(failed)}")
        end
      end

      {:ok, sim} = Sim.Worlds.lookup(fleet.wdf)
      goals = for i <- 1..fleet.n, do: give_goal(i, Enum.at(fleet.goals, i - 1))
      # settle: every robot sensing and planning
      Process.sleep(2_000)
      recorders = if record?, do: Enum.map(1..fleet.n, &BlackBox.recorder(robot(&1))), else: []
      tracer = if record?, do: start_tracer(recorders)
      # the node's batch sender works for the recorders (their lists)
      sender = if record?, do: Process.whereis(ThinkingCap.Blackboard.Core.Batches)
      sender_tracer = if sender, do: start_tracer([sender])
      before = snapshot(sim, recorders, rec_dir)
      # the machine's own stalls in the same window (a wake-up a ms)
      probe = Cyclictest.start(round(seconds / fleet.speed) + 600, 1_000)
      hogs = start_hog_monitor()
      wall0 = System.monotonic_time(:microsecond)
      goals = drive(fleet, sim, before.sim_time + seconds, goals)
      wall = (System.monotonic_time(:microsecond) - wall0) / 1.0e6
      machine = Cyclictest.stop(probe, 10_000)
      hogs = stop_hog_monitor(hogs)
      after_ = snapshot(sim, recorders, rec_dir)

      if sender_tracer,
        do: :erlang.trace(sender, false, [:running, :garbage_collection, :timestamp])

      {cpu_us, runs, {gc_us, gc_n}, longest} =
        if tracer, do: stop_tracer(tracer), else: {0, 0, {0, 0}, []}

      {sender_us, _, _, _} =
        if sender_tracer, do: tracer_total(sender_tracer), else: {0, 0, {0, 0}, []}

      _ = goals

      %{
        record?: record?,
        wall: wall,
        sim_seconds: after_.sim_time - before.sim_time,
        lagged: after_.lagged - before.lagged,
        control_misses: misses(after_.timing, before.timing, "control_", :fallbacks),
        control_cycles: misses(after_.timing, before.timing, "control_", :cycles),
        control_tails: tails(after_.timing, before.timing, "control_"),
        machine: machine,
        hogs: hogs,
        base_misses: misses(after_.timing, before.timing, "base_", :fallbacks),
        base_cycles: misses(after_.timing, before.timing, "base_", :cycles),
        vm_cpu_ms: after_.vm_cpu_ms - before.vm_cpu_ms,
        tuples: after_.tuples - before.tuples,
        messages: after_.messages - before.messages,
        dropped: after_.dropped,
        bytes: after_.bytes - before.bytes,
        recorder_cpu_us: cpu_us,
        recorder_gc_us: gc_us,
        recorder_gcs: gc_n,
        sender_cpu_us: sender_us,
        recorder_runs: runs,
        recorder_longest: longest,
        files:
          if(record?,
            do: Map.new(1..fleet.n, &{robot(&1), recording_files(rec_dir, robot(&1))}),
            else: %{}
          )
      }
    after
      stop_fleet(adfs, fleet)
    end
  end

  defp recording_files(dir, robot),
    do: Path.wildcard(Path.join(dir, "#{robot}_*.mcap")) |> Enum.sort()

  defp adf(fleet, i, record?, rec_dir) do
    {x, y, th} = Enum.at(fleet.starts, i - 1)
    r = robot(i)

    """
    [
      robot: #{inspect(r)},
      rdf: #{inspect(@rdf)},
      wdf: #{inspect(fleet.wdf)},
      dashboard: [enabled: false],
      black_box: [enabled: false],
      record: [enabled: #{record?}, dir: #{inspect(rec_dir)},
               chunk_seconds: #{1.0 / fleet.speed}, file_seconds: #{600.0 / fleet.speed}],
      modules: [
        base_#{i}: [module: ThinkingCap.Sim.Robot, activity: :periodic,
                    period: #{fleet.step / fleet.speed}, deadline: 0.003, priority: 90, fallback: :stop,
                    params: [at: #{inspect({x, y, th})}, seed: 1, step: #{fleet.step},
                             speed: #{fleet.speed}, command_timeout: #{0.5 / fleet.speed}]],
        perception_#{i}: [module: ThinkingCap.Perception.Fuser, activity: :event, layer: :reactive],
        localization_#{i}: [module: ThinkingCap.Navigation.Localizer, activity: :event,
                            params: [initial: #{inspect({x, y, th})}, initial_sigma: {0.1, 0.05}]],
        control_#{i}: [module: ThinkingCap.Control.Blender, activity: :periodic,
                       period: #{0.1 / fleet.speed},
                       deadline: 0.05, priority: 80,
                       params: [behaviours: [:avoid, :go_to, :follow_wall]]]
      ]
    ]
    """
  end

  defp give_goal(i, {x, y}) do
    {plan, opts} =
      Tuples.keyed(Tuples.plan(robot(i), %{goal: {x, y}, state: :going, task: {:go_to, {x, y}}}))

    Blackboard.out(plan, opts)
    {x, y}
  end

  # runs until the simulation's clock reaches `until`, giving a robot at
  # its goal the next (its start and goal swapped)
  defp drive(fleet, sim, until, goals) do
    if Sim.time(sim) >= until do
      goals
    else
      Process.sleep(500)

      goals =
        for {goal, i} <- Enum.with_index(goals, 1) do
          case Blackboard.rdp(Tuples.pose(robot(i))) do
            {:ok, Tuples.pose(_, %{pose: {x, y, _}})} ->
              {gx, gy} = goal

              if :math.sqrt((x - gx) ** 2 + (y - gy) ** 2) < 0.6 do
                {sx, sy, _} = Enum.at(fleet.starts, i - 1)

                next =
                  if goal == Enum.at(fleet.goals, i - 1),
                    do: {sx, sy},
                    else: Enum.at(fleet.goals, i - 1)

                give_goal(i, next)
              else
                goal
              end

            _ ->
              goal
          end
        end

      drive(fleet, sim, until, goals)
    end
  end

  defp snapshot(sim, recorders, rec_dir) do
    status = GenServer.call(sim, :status, 120_000)
    infos = for pid <- recorders, pid, do: GenServer.call(pid, :info, 120_000)

    bytes =
      Path.wildcard(Path.join(rec_dir, "*.mcap"))
      |> Enum.map(&File.stat!(&1).size)
      |> Enum.sum()

    %{
      sim_time: status.time,
      lagged: Map.get(status, :lagged, 0),
      timing: Cycle.timing(),
      vm_cpu_ms: vm_cpu_ms(),
      tuples: Enum.sum(Enum.map(infos, &(&1.messages - &1.callbacks))),
      messages: Enum.sum(Enum.map(infos, & &1.messages)),
      dropped: Enum.sum(Enum.map(infos, & &1.dropped)),
      bytes: bytes
    }
  end

  # how many of the control cycles' releases, responses, cycles and CPU
  # times fell in each power-of-two bucket of 8 ms and more (`Cycle.Stats`'
  # histograms), summed over the robots: where a miss's time went
  defp tails(after_, before, prefix) do
    for key <- [:jitter_us, :response_us, :cycle_us, :cpu_us], into: %{} do
      counts =
        for {name, s} <- after_,
            String.starts_with?(Atom.to_string(name), prefix),
            {bucket, n} <- Map.get(s[key], :hist, %{}),
            bucket >= 14,
            reduce: %{} do
          acc ->
            was = get_in(before, [name, key, :hist, bucket]) || 0
            Map.update(acc, bucket, n - was, &(&1 + n - was))
        end

      {key, counts |> Enum.reject(&(elem(&1, 1) == 0)) |> Enum.sort()}
    end
  end

  defp misses(after_, before, prefix, key) do
    for {name, s} <- after_, String.starts_with?(Atom.to_string(name), prefix), reduce: 0 do
      acc -> acc + s[key] - (get_in(before, [name, key]) || 0)
    end
  end

  # the VM's user and system CPU time, ms
  defp vm_cpu_ms do
    {:ok, stat} = File.read("/proc/self/stat")
    [_, rest] = String.split(stat, ") ", parts: 2)
    fields = String.split(rest)
    ticks = String.to_integer(Enum.at(fields, 11)) + String.to_integer(Enum.at(fields, 12))
    div(ticks * 1000, ProcStat.clock_ticks())
  end

  ## What held a scheduler: OTP's system monitor

  # long_schedule: a process or port that ran @hog_ms or more without
  # yielding its scheduler (a NIF, a BIF, a port's work); long_gc: a
  # collection that long. Either keeps every other process of that
  # scheduler waiting, the robots' hosts too.
  defp start_hog_monitor do
    pid = spawn(fn -> hog_loop(%{}) end)
    :erlang.system_monitor(pid, [{:long_schedule, @hog_ms}, {:long_gc, @hog_ms}])
    pid
  end

  defp stop_hog_monitor(pid) do
    :erlang.system_monitor(:undefined)
    send(pid, {:stop, self()})

    receive do
      {:hogs, hogs} -> hogs
    after
      5_000 -> %{}
    end
  end

  defp hog_loop(acc) do
    receive do
      {:monitor, who, kind, info} when kind in [:long_schedule, :long_gc] ->
        ms = info[:timeout]
        # a schedule: where it began; a collection: the heap's words (young and old)
        where =
          if kind == :long_schedule,
            do: info[:in],
            else: {:words_up_to, pow2(info[:heap_block_size] + info[:old_heap_block_size])}

        key = {kind, describe(who), where}
        hog_loop(Map.update(acc, key, {1, ms}, fn {n, m} -> {n + 1, max(m, ms)} end))

      {:monitor, _, _, _} ->
        hog_loop(acc)

      {:stop, from} ->
        send(from, {:hogs, acc})
    end
  end

  defp pow2(n), do: 2 ** ceil(:math.log2(max(n, 1)))

  # a process by its registered name or the module it runs
  defp describe(port) when is_port(port), do: "a port"

  defp describe(pid) do
    case Process.info(pid, [:registered_name, :dictionary]) do
      [registered_name: name, dictionary: _] when is_atom(name) and name != [] ->
        inspect(name)

      [registered_name: _, dictionary: dict] ->
        case {dict[:"$tc_spec"], dict[:"$initial_call"]} do
          # a module's host: its module's kind, not each robot's name
          {%{module: m}, _} -> "the host of #{inspect(m)}"
          {_, {m, _, _}} -> inspect(m)
          _ -> "a process"
        end

      nil ->
        "a process gone"
    end
  end

  ## CPU time of the recorders, per process

  defp start_tracer(pids) do
    parent = self()

    tracer =
      spawn_link(fn ->
        receive do
          :go -> :ok
        end

        send(parent, :tracing)
        tracer_loop(%{}, 0, 0, %{}, {0, 0})
      end)

    Process.flag(:priority, :normal)
    :erlang.trace(:all, true, [:cpu_timestamp])

    for pid <- pids,
        pid,
        do:
          :erlang.trace(pid, true, [:running, :garbage_collection, :timestamp, {:tracer, tracer}])

    send(tracer, :go)

    receive do
      :tracing -> tracer
    end
  end

  # the recorders' CPU time (µs), how many times they were scheduled, and
  # the part of that time their garbage collections took, and how many
  defp tracer_loop(ins, total, runs, gcs, {gc, gc_n} = gc_sum) do
    receive do
      {:trace_ts, pid, kind, mfa, ts} when kind in [:in, :in_exiting] ->
        tracer_loop(Map.put(ins, pid, {ts, mfa}), total, runs, gcs, gc_sum)

      {:trace_ts, pid, kind, _mfa, ts} when kind in [:out, :out_exiting, :out_exited] ->
        case Map.pop(ins, pid) do
          {nil, ins} ->
            tracer_loop(ins, total, runs, gcs, gc_sum)

          {{t_in, mfa}, ins} ->
            us = :timer.now_diff(ts, t_in)
            note_schedule(us, mfa)
            tracer_loop(ins, total + us, runs + 1, gcs, gc_sum)
        end

      {:trace_ts, pid, kind, _info, ts} when kind in [:gc_minor_start, :gc_major_start] ->
        tracer_loop(ins, total, runs, Map.put(gcs, pid, ts), gc_sum)

      {:trace_ts, pid, kind, _info, ts} when kind in [:gc_minor_end, :gc_major_end] ->
        case Map.pop(gcs, pid) do
          {nil, gcs} ->
            tracer_loop(ins, total, runs, gcs, gc_sum)

          {t0, gcs} ->
            tracer_loop(ins, total, runs, gcs, {gc + :timer.now_diff(ts, t0), gc_n + 1})
        end

      {:stop, from} ->
        send(
          from,
          {:cpu_us, total, runs, gc_sum, longest_schedules()}
        )
    end
  end

  # by the function a schedule began in: the longest (µs of CPU) and how
  # many took 1 ms or more. A process queued behind a long one on a
  # normal scheduler waits for it (the chunk's compression and the
  # file's writes run on dirty schedulers)
  defp note_schedule(us, mfa) do
    {longest, long} = Process.get({:schedules, mfa}, {0, 0})
    Process.put({:schedules, mfa}, {max(us, longest), long + if(us >= 1000, do: 1, else: 0)})
  end

  # the three of longest schedules: [{µs, schedules of 1 ms or more, mfa}]
  defp longest_schedules do
    for({{:schedules, mfa}, {us, long}} <- Process.get(), do: {us, long, mfa})
    |> Enum.sort(:desc)
    |> Enum.take(3)
  end

  defp stop_tracer(tracer) do
    pids =
      for {pid, _} <-
            Registry.select(ThinkingCap.BlackBox.Registry, [
              {{:"$1", :"$2", :_}, [], [{{:"$2", :"$1"}}]}
            ]),
          do: pid

    stop_tracer(tracer, pids)
  end

  defp stop_tracer(tracer, pids) do
    for pid <- pids, do: :erlang.trace(pid, false, [:running, :garbage_collection, :timestamp])
    :erlang.trace(:all, false, [:cpu_timestamp])
    tracer_total(tracer)
  end

  # the trace messages sent so far are in the tracer's queue
  defp tracer_total(tracer) do
    send(tracer, {:stop, self()})

    receive do
      {:cpu_us, us, runs, gc, longest} -> {us, runs, gc, longest}
    after
      60_000 -> Mix.raise("the CPU tracer did not answer")
    end
  end

  # The CPU one schedule of a process that does nothing costs, traced as
  # the recorders are: the cpu_timestamp clock's reads and the trace
  # messages, and the switch itself. A process answering 2,000 pings
  # one at a time, the least of three rounds.
  defp traced_idle_schedule_us do
    Enum.min(for _ <- 1..3, do: idle_round(2_000))
  end

  defp idle_round(n) do
    echo = spawn(fn -> echo_loop() end)
    tracer = start_tracer([echo])

    for _ <- 1..n do
      send(echo, {:ping, self()})

      receive do
        :pong -> :ok
      end
    end

    :erlang.trace(echo, false, [:running, :garbage_collection, :timestamp])
    :erlang.trace(:all, false, [:cpu_timestamp])
    send(tracer, {:stop, self()})
    Process.exit(echo, :kill)

    receive do
      {:cpu_us, us, runs, _gc, _longest} -> us / max(runs, 1)
    after
      60_000 -> Mix.raise("the CPU tracer did not answer")
    end
  end

  defp echo_loop do
    receive do
      {:ping, from} ->
        send(from, :pong)
        echo_loop()
    end
  end

  ## Setup and teardown

  # start poses (free, 1.2 m apart) and goals (free, at least 10 m away)
  defp places(world, n) do
    grid = world.wdf.grid
    rng = :rand.seed_s(:exsss, {17, n, 3})

    {starts, rng} =
      Enum.reduce(1..n, {[], rng}, fn _, {acc, rng} ->
        {p, rng} =
          free_place(world, grid, rng, fn {x, y} ->
            Enum.all?(acc, fn {ax, ay, _} -> (ax - x) ** 2 + (ay - y) ** 2 > 1.44 end)
          end)

        {th, rng} = :rand.uniform_s(rng)
        {x, y} = p
        {[{x, y, (th - 0.5) * 2 * :math.pi()} | acc], rng}
      end)

    starts = Enum.reverse(starts)

    {goals, _} =
      Enum.map_reduce(starts, rng, fn {sx, sy, _}, rng ->
        free_place(world, grid, rng, fn {x, y} -> (sx - x) ** 2 + (sy - y) ** 2 > 100 end)
      end)

    {starts, goals}
  end

  defp free_place(world, grid, rng, ok?) do
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    {col, row} = {floor(u * grid.width), floor(v * grid.height)}
    {ox, oy, _} = grid.origin
    x = ox + (col + 0.5) * grid.resolution
    y = oy + (row + 0.5) * grid.resolution

    if ThinkingCap.Config.RosMap.cell(grid, col, row) == 0 and
         Sim.World.free?(world, {x, y}, 0.2 + 0.4) and ok?.({x, y}),
       do: {{x, y}, rng},
       else: free_place(world, grid, rng, ok?)
  end

  defp stop_fleet(adfs, fleet) do
    for adf <- adfs, m <- adf.modules, do: Runtime.stop({adf.robot, m.name})
    for adf <- adfs, do: BlackBox.stop(adf.robot)

    case Sim.Worlds.lookup(fleet.wdf) do
      {:ok, sim} -> DynamicSupervisor.terminate_child(ThinkingCap.Sim.Supervisor, sim)
      :error -> :ok
    end

    for adf <- adfs do
      drain({:_, adf.robot, :_})
      for m <- adf.modules, m.activity == :periodic, do: drain(Tuples.timing(m.name))
    end
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  ## Replay

  defp replay([]), do: {0.0, "no recording"}

  defp replay(files) do
    {:ok, rec} = Replay.open(files)
    names = for m <- Replay.modules(rec), do: m.name
    {:ok, reports} = Replay.compare(rec, names)

    text =
      Enum.map_join(Enum.sort(reports), "; ", fn {name, r} ->
        "#{name} #{r.equal}/#{r.outputs}" <>
          if(r.stopped, do: " (stopped: #{r.stopped})", else: "")
      end)

    {Replay.equal_pct(reports), text}
  end

  defp load do
    case File.read("/proc/loadavg") do
      {:ok, s} -> s |> String.split() |> Enum.take(3) |> Enum.join(" ")
      _ -> "?"
    end
  end

  defp fmt(x, d), do: :erlang.float_to_binary(x * 1.0, decimals: d)
end
