defmodule ThinkingCap.FaultSuite.SerialFaultsTest do
  # A real robot's view: a Create 2 (the emulator, on a pty) driven by a
  # peer node whose timing worker owns the serial command path. The node
  # dies as a power loss or a crash would; the wheels must stop.
  use ExUnit.Case, async: false

  import ThinkingCap.FaultSuite.Case,
    only: [start_stall_probe: 0, machine_stalls: 1, assert_uncommanded_within: 3]

  alias ThinkingCap.{Blackboard, Runtime}
  alias ThinkingCap.FaultSuite.Tally
  alias ThinkingCap.Testing.{Cluster, Create2Emulator}

  @moduletag :faults
  @moduletag :tmp_dir

  @rdf Path.expand("../../priv/examples/create2.rdf", __DIR__)

  # A Create 2 emulator on a pty, and a peer node whose Create 2 driver
  # (its timing worker owning the serial command path) drives it forward
  defp driving_create2(dir) do
    link = Path.join(dir, "create2")
    emu = start_supervised!({Create2Emulator, link: link})

    robot = :"s#{System.unique_integer([:positive])}"
    adf = Path.join(dir, "#{robot}.adf")

    File.write!(adf, """
    [
      robot: :#{robot},
      rdf: #{inspect(@rdf)},
      modules: [
        base: [module: ThinkingCap.Robot.Create2, activity: :periodic, period: 0.01,
               deadline: 0.003, fallback: :stop,
               params: [device: #{inspect(link)}, command_timeout: 30.0]]
      ]
    ]
    """)

    [node] = Cluster.start(1, apps: [:tc_robot])
    on_exit(fn -> Cluster.stop(node) end)
    assert {:ok, _} = Cluster.call(node, Runtime, :start, [adf])

    command = {:drive, robot, %{command: {:velocity, 0.2, 0.0}}}
    :ok = Cluster.call(node, Blackboard, :out, [command, [key: {:drive, robot}]])
    Cluster.wait_until(fn -> match?(%{left: 200, right: 200}, Create2Emulator.state(emu)) end)
    {emu, node}
  end

  test "the node driving a Create 2 dies: its timing worker puts the stop on the wire at once",
       %{tmp_dir: dir} do
    {emu, node} = driving_create2(dir)
    Process.sleep(200)

    probe = start_stall_probe()
    killed_at = System.monotonic_time()
    Tally.injected()
    Cluster.kill(node)

    Cluster.wait_until(fn -> match?(%{left: 0, right: 0}, Create2Emulator.state(emu)) end)

    # on the wire: the last moving command and the stop after it (a missed
    # deadline before the kill puts a fallback stop between moving commands)
    commands = Create2Emulator.commands(emu)
    moving? = &(&1.command == {:drive_direct, 200, 200})

    {after_last_moving, [last_moving | _]} =
      commands |> Enum.reverse() |> Enum.split_while(&(not moving?.(&1)))

    stop =
      after_last_moving |> Enum.reverse() |> Enum.find(&(&1.command == {:drive_direct, 0, 0}))

    # the stop after the last moving command. It may precede the kill by a
    # cycle: a deadline missed just before it (the node going down, or the
    # machine) stopped the wheels first, and nothing moved them again. An
    # older stop (a cycle and the machine's worst stall before) would not
    # be the kill's.
    assert stop != nil
    machine = machine_stalls(probe)
    cycle_and_stall = System.convert_time_unit(round(13 + machine.max_ms), :millisecond, :native)
    assert stop.at >= killed_at - cycle_and_stall

    uncommanded = System.convert_time_unit(stop.at - last_moving.at, :native, :microsecond) / 1000
    Tally.uncommanded(uncommanded)
    # a period, and the moment the worker takes to see its BEAM gone, plus
    # what the machine itself did to every real-time thread meanwhile
    assert_uncommanded_within(uncommanded, 13, machine)

    Tally.survived()
  end

  test "the node driving a Create 2 freezes for 15 s: its timing worker stops the wheels every cycle",
       %{tmp_dir: dir} do
    {emu, node} = driving_create2(dir)
    os_pid = Cluster.call(node, System, :pid, [])
    Process.sleep(200)

    # the BEAM stopped as a debugger or a swapped-out machine would stop
    # it: it reads nothing from its timing worker. The worker goes on
    # releasing, missing deadlines and putting the fallback (the stop) on
    # the wire every 10 ms, and its frames to the BEAM pile up in the
    # pipe between them.
    probe = start_stall_probe()
    Tally.injected()
    {_, 0} = System.cmd("kill", ["-STOP", os_pid])
    frozen_at = System.monotonic_time()
    Process.sleep(15_000)
    thawed_at = System.monotonic_time()
    {_, 0} = System.cmd("kill", ["-CONT", os_pid])
    machine = machine_stalls(probe)

    # the stops while it was frozen
    window =
      emu
      |> Create2Emulator.commands()
      |> Enum.filter(&(&1.at >= frozen_at and &1.at < thawed_at))
      |> Enum.filter(&(&1.command == {:drive_direct, 0, 0}))

    gaps =
      window
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.map(fn [a, b] ->
        System.convert_time_unit(b.at - a.at, :native, :microsecond) / 1000
      end)

    # a stop a cycle (10 ms) for the whole 15 s; a gap no longer than a
    # cycle and the deadline plus the machine's own worst stall. With the
    # pipe at its default 64 KB the worker's write to its BEAM blocked
    # about 11 s in, and the stops with it.
    assert length(window) >= 1_000, "#{length(window)} stops in 15 s"
    last = System.convert_time_unit(List.last(window).at - frozen_at, :native, :millisecond)
    assert last >= 14_900, "the last stop came #{last} ms into the 15 s"
    assert_uncommanded_within(Enum.max(gaps), 13, machine)

    Tally.survived()
  end

  test "SIGTERM on the node driving a Create 2: the stop is the last frame, the node gone in 5 s",
       %{tmp_dir: dir} do
    {emu, node} = driving_create2(dir)

    os_pid = Cluster.call(node, System, :pid, [])
    Tally.injected()
    sent_at = System.monotonic_time(:millisecond)
    {_, 0} = System.cmd("kill", ["-TERM", os_pid])

    # the node's OS process ends within 5 s
    gone_at =
      Enum.find_value(1..120, fn _ ->
        Process.sleep(50)
        {_, status} = System.cmd("kill", ["-0", os_pid], stderr_to_stdout: true)
        if status != 0, do: System.monotonic_time(:millisecond)
      end)

    assert gone_at, "the node still runs 6 s after SIGTERM"
    assert gone_at - sent_at <= 5_000

    # the wheels stopped, and the last command on the wire is the stop
    assert %{left: 0, right: 0} = Create2Emulator.state(emu)

    last_drive =
      emu
      |> Create2Emulator.commands()
      |> Enum.filter(&match?({:drive_direct, _, _}, &1.command))
      |> List.last()

    assert last_drive.command == {:drive_direct, 0, 0}
    Tally.survived()
  end
end
