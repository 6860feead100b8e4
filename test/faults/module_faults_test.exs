defmodule ThinkingCap.FaultSuite.ModuleFaultsTest do
  # Faults inside one node: a module process killed, the timing worker
  # killed, a module made slow. The robot is a test robot's base, released
  # every 10 ms with a 3 ms deadline, driven by an autonomous command.
  use ExUnit.Case, async: false

  import ThinkingCap.FaultSuite.Case

  alias ThinkingCap.{Blackboard, Cycle, Runtime}
  alias ThinkingCap.FaultSuite.Tally
  alias ThinkingCap.Testing.Cluster

  @moduletag :faults
  @moduletag :tmp_dir

  # one period plus the deadline: the longest a robot may run on a
  # command before the next one (fresh or the fallback) is applied
  @bound_ms 10 + 3

  setup %{tmp_dir: dir} do
    {robot, names} = start_robot(dir)
    autonomy(robot)
    observer = observe(names.base)
    await_event(observer, -1.0e18, &(&1.kind == :fresh and &1.command == {:velocity, 0.2, 0.0}))
    %{robot: robot, base: names.base, observer: observer}
  end

  # tuples that must outlive a fault: written before it, checked after
  defp write_notes(robot, n) do
    for i <- 1..n, do: :ok = Blackboard.out({:note, robot, %{i: i}})
    n
  end

  defp notes_lost(robot, n), do: n - length(Blackboard.rd_all({:note, robot, :_}))

  test "a killed module is restarted, its fallback applied meanwhile, no tuple lost", ctx do
    notes = write_notes(ctx.robot, 1_000)
    pid = Runtime.whereis(ctx.base)
    probe = start_stall_probe()
    t0 = now_ms()

    Tally.injected()
    Process.exit(pid, :kill)

    # the fallback holds while it is down, then it drives again
    await_event(ctx.observer, t0, &(&1.kind == :fallback and &1.command == :stop))
    Cluster.wait_until(fn -> Runtime.whereis(ctx.base) not in [nil, pid] end)

    resumed =
      await_event(
        ctx.observer,
        t0,
        &(&1.kind == :fresh and &1.command == {:velocity, 0.2, 0.0})
      )

    uncommanded = uncommanded_ms(events(ctx.observer), t0 - 100)
    Tally.uncommanded(uncommanded)
    lost = notes_lost(ctx.robot, notes)
    Tally.lost(lost)

    assert resumed.at > t0
    assert lost == 0
    assert_uncommanded_within(uncommanded, @bound_ms, machine_stalls(probe))
    Tally.survived()
  end

  test "a killed timing worker: the robot stops, the worker restarts, control resumes", ctx do
    restarts = Cycle.status().restarts
    probe = start_stall_probe()
    t0 = now_ms()

    Tally.injected()
    {_, 0} = System.cmd("kill", ["-9", "#{Cycle.worker_os_pid()}"])

    # the restart's own report (cycle 0): every activity's fallback holds
    stopped = await_event(ctx.observer, t0, &(&1.kind == :fallback and &1.cycle == 0))
    Cluster.wait_until(fn -> Cycle.status().restarts == restarts + 1 end)

    Cluster.wait_until(fn ->
      match?({:ok, {:driven, _, %{command: :stop}}}, Blackboard.rdp({:driven, ctx.robot, :_}))
    end)

    await_event(ctx.observer, stopped.at, &(&1.kind == :fresh and &1.command != :stop))

    # From the last command applied before the kill to the stop: up to a
    # period, plus the time the OS takes to tell the BEAM that the worker
    # died (a few ms on a quiet machine, tens under load), plus whatever
    # this shared machine stalled its CPUs meanwhile (cyclictest's worst
    # wake-up: runs of 70-110 ms were seen, each time with a CPU-bound
    # neighbour). Nothing on the machine can stop the robot faster when the
    # worker itself is gone; a motor controller's own serial watchdog can.
    machine = machine_stalls(probe)
    uncommanded = uncommanded_ms(events(ctx.observer), t0 - 100)
    Tally.uncommanded(uncommanded)
    assert_uncommanded_within(uncommanded, 100, machine)

    Tally.survived()
  end

  test "a slow module misses its deadlines: fallbacks applied and counted, nothing else delayed",
       ctx do
    {_robot, names} =
      start_robot(ctx.tmp_dir,
        slow:
          "[module: ThinkingCap.Test.Modules.Slow, activity: :periodic, period: 0.02, deadline: 0.005, fallback: :halt, params: [sleep_ms: 30]]"
      )

    slow = observe(names.slow)
    probe = start_stall_probe()
    t0 = now_ms()

    Tally.injected()
    await_event(slow, t0, &(&1.kind == :fallback and &1.command == :halt))
    before = Runtime.timing()[ctx.base]
    Process.sleep(2_000)
    timing = Runtime.timing()

    assert timing[names.slow].fallbacks >= 20
    assert timing[names.slow].late >= 1
    # every slow release was covered: its fallback came in its own cycle
    assert uncommanded_ms(events(slow), t0) == 0.0

    # the robot's base beside it kept its deadline, as far as the machine
    # let it (cyclictest alongside)
    machine = machine_stalls(probe)
    base_cycles = timing[ctx.base].cycles - before.cycles
    assert base_cycles >= 150
    assert_kept_deadline(base_cycles, timing[ctx.base].fallbacks - before.fallbacks, machine)

    uncommanded = uncommanded_ms(events(ctx.observer), t0)
    Tally.uncommanded(uncommanded)
    assert_uncommanded_within(uncommanded, @bound_ms, machine)
    Tally.survived()
  end
end
