defmodule ThinkingCap.RobotTest do
  # Hosts robot drivers in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}
  alias ThinkingCap.Robot.UART
  alias ThinkingCap.Testing.Cluster
  alias ThinkingCap.Testing.Robot, as: TestRobot

  @moduletag :tmp_dir

  @rdf """
  [
    name: "test-diff",
    footprint: [radius: 0.2],
    kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.16, max_speed: 0.5],
    sensors: [[name: :bumper, type: :bumper]]
  ]
  """

  defp start(dir, params, robot \\ nil) do
    {robot, base, adf} = write_adf(dir, params, robot)
    # ended with its test, for good (a killed one's restarted copy too)
    on_exit(fn ->
      assert Runtime.stop(base) in [:ok, {:error, :not_running}]
      assert Runtime.whereis(base) == nil
    end)

    {:ok, _} = Runtime.start(Config.read!(adf))
    {robot, base}
  end

  defp write_adf(dir, params, robot) do
    robot = robot || :"t#{System.unique_integer([:positive])}"
    base = :"base_#{robot}"
    File.write!(Path.join(dir, "r.rdf"), @rdf)

    File.write!(Path.join(dir, "#{robot}.adf"), """
    [
      robot: :#{robot},
      rdf: "r.rdf",
      modules: [
        #{base}: [module: ThinkingCap.Testing.Robot, activity: :periodic, period: 0.01,
                  deadline: 0.005, fallback: :stop, params: #{inspect(params)}]
      ]
    ]
    """)

    {robot, base, Path.join(dir, "#{robot}.adf")}
  end

  defp drive(robot, command),
    do: Blackboard.out({:drive, robot, %{command: command}}, key: {:drive, robot})

  # waits for the robot to be driven with `command`
  defp driven(robot, command, timeout \\ 5000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    wait_driven(robot, command, deadline)
  end

  defp wait_driven(robot, command, deadline) do
    case Blackboard.rdp({:driven, robot, :_}) do
      {:ok, {:driven, ^robot, %{command: ^command} = d}} ->
        d

      _ ->
        if System.monotonic_time(:millisecond) > deadline do
          flunk(
            "#{inspect(robot)} was not driven with #{inspect(command)}: " <>
              inspect(Blackboard.rdp({:driven, robot, :_}))
          )
        end

        Process.sleep(5)
        wait_driven(robot, command, deadline)
    end
  end

  test "publishes its capabilities, follows drive commands, stops when they go stale", %{
    tmp_dir: dir
  } do
    {robot, _base} = start(dir, command_timeout: 0.5)

    assert {:ok, {:robot, ^robot, caps}} = Blackboard.rd({:robot, robot, :_}, 1000)
    assert caps.drive == :differential
    assert caps.limits.max_speed == 0.5
    assert [%{name: :bumper, type: :bumper}] = caps.sensors

    # no command yet: stopped
    driven(robot, :stop)

    sent = System.monotonic_time(:millisecond)
    drive(robot, {:velocity, 0.2, 0.1})
    driven(robot, {:velocity, 0.2, 0.1})
    assert %{command: {:velocity, 0.2, 0.1}} = control(robot, :autonomy)

    # nobody commands any more: the robot idles, stopped, once the command
    # is older than command_timeout (received after it was sent: never
    # sooner than that after sending). Idle, not a deadline missed under
    # load, whose fallback stops it too, for a cycle.
    assert %{command: :stop} = control(robot, :idle)
    assert System.monotonic_time(:millisecond) - sent >= 500
  end

  defp teleop(robot, command, extra \\ %{}),
    do:
      Blackboard.out({:teleop, robot, Map.merge(%{command: command}, extra)},
        key: {:teleop, robot}
      )

  defp estop(robot, engaged),
    do: Blackboard.out({:estop, robot, %{engaged: engaged}}, key: {:estop, robot})

  defp control(robot, mode, timeout \\ 5000) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      case Blackboard.rdp({:control, robot, :_}) do
        {:ok, {:control, ^robot, %{mode: ^mode} = c}} ->
          c

        other ->
          if System.monotonic_time(:millisecond) > deadline,
            do: flunk("#{inspect(robot)} never in #{mode}: #{inspect(other)}")

          Process.sleep(5)
          nil
      end
    end)
    |> Enum.find(& &1)
  end

  test "teleoperation overrides autonomy while it is refreshed, and hands it back", %{
    tmp_dir: dir
  } do
    # teleoperation expires only after the test: only its release hands back
    {robot, _base} = start(dir, command_timeout: 30.0, teleop_timeout: 30.0)

    drive(robot, {:velocity, 0.1, 0.0})
    driven(robot, {:velocity, 0.1, 0.0})
    assert %{command: {:velocity, 0.1, 0.0}} = control(robot, :autonomy)

    teleop(robot, {:velocity, 0.4, 0.2}, %{by: "tester", sent_at: 1234.5})
    driven(robot, {:velocity, 0.4, 0.2})
    # who drives, and the client's stamp echoed back
    assert %{teleop_by: "tester", teleop_sent_at: 1234.5} = control(robot, :teleop)

    # released: autonomy's command again, not when teleoperation expires
    teleop(robot, :release)
    driven(robot, {:velocity, 0.1, 0.0})
    assert %{command: {:velocity, 0.1, 0.0}} = control(robot, :autonomy)
  end

  test "the deadman rule: teleoperation not refreshed expires and the robot stops", %{
    tmp_dir: dir
  } do
    {robot, _base} = start(dir, teleop_timeout: 0.3)
    sent = System.monotonic_time(:millisecond)
    teleop(robot, {:velocity, 0.3, 0.0})
    driven(robot, {:velocity, 0.3, 0.0})
    assert %{command: {:velocity, 0.3, 0.0}} = control(robot, :teleop)
    # no autonomy either: idle, stopped, once the teleoperation command is
    # stale, never sooner than teleop_timeout after it was sent
    assert %{command: :stop} = control(robot, :idle)
    assert System.monotonic_time(:millisecond) - sent >= 300
  end

  test "an E-stop stops the robot over teleoperation and autonomy until released", %{
    tmp_dir: dir
  } do
    {robot, _base} = start(dir, command_timeout: 5.0, teleop_timeout: 5.0)
    drive(robot, {:velocity, 0.2, 0.0})
    teleop(robot, {:velocity, 0.4, 0.0})
    driven(robot, {:velocity, 0.4, 0.0})

    estop(robot, true)
    driven(robot, :stop)
    control(robot, :estop)
    # fresh commands do not undo it
    teleop(robot, {:velocity, 0.5, 0.0})
    drive(robot, {:velocity, 0.5, 0.0})
    Process.sleep(50)
    assert {:ok, {:driven, ^robot, %{command: :stop}}} = Blackboard.rdp({:driven, robot, :_})

    estop(robot, false)
    driven(robot, {:velocity, 0.5, 0.0})
    control(robot, :teleop)
  end

  test "a latched E-stop holds for a driver that starts after it", %{tmp_dir: dir} do
    robot = :"t#{System.unique_integer([:positive])}"
    estop(robot, true)
    {^robot, _base} = start(dir, [command_timeout: 5.0], robot)
    drive(robot, {:velocity, 0.2, 0.0})
    control(robot, :estop)
    Process.sleep(50)
    assert {:ok, {:driven, ^robot, %{command: :stop}}} = Blackboard.rdp({:driven, robot, :_})
    estop(robot, false)
    driven(robot, {:velocity, 0.2, 0.0})
  end

  test "a command the drive cannot take is refused and the robot stops", %{tmp_dir: dir} do
    {robot, _base} = start(dir, [])
    drive(robot, {:velocity, 0.3, 0.0})
    driven(robot, {:velocity, 0.3, 0.0})
    # a differential robot has no steering
    drive(robot, {:steer, 0.3, 0.2})
    driven(robot, :stop)
    drive(robot, {:wheels, 2.0, 2.0})
    driven(robot, {:wheels, 2.0, 2.0})
  end

  test "when the hardware refuses a command, the robot is stopped", %{tmp_dir: dir} do
    {robot, _base} = start(dir, refuse: [:wheels])
    drive(robot, {:velocity, 0.3, 0.0})
    driven(robot, {:velocity, 0.3, 0.0})
    drive(robot, {:wheels, 1.0, 1.0})
    driven(robot, :stop)
  end

  test "readings from the hardware are published as latest-value tuples", %{tmp_dir: dir} do
    {robot, base} = start(dir, [])
    TestRobot.feed(base, [{:bumper, %{pressed: true, stamp: 1.0}}])
    assert {:ok, {:bumper, ^robot, %{pressed: true}}} = Blackboard.rd({:bumper, robot, :_}, 1000)
    TestRobot.feed(base, [{:bumper, %{pressed: false, stamp: 2.0}}])
    Process.sleep(50)
    assert [{:bumper, ^robot, %{pressed: false}}] = Blackboard.rd_all({:bumper, robot, :_})
  end

  test "a robot stopped by the runtime is left stopped", %{tmp_dir: dir} do
    {robot, base} = start(dir, [])
    drive(robot, {:velocity, 0.3, 0.0})
    %{count: n} = driven(robot, {:velocity, 0.3, 0.0})
    :ok = Runtime.stop(base)

    assert {:ok, {:driven, ^robot, %{command: :stop, count: m}}} =
             Blackboard.rdp({:driven, robot, :_})

    assert m > n
  end

  describe "the timing worker owns the line (wire:)" do
    @velocity "{:velocity, 0.2, 0.0}"

    test "the arbitrated command is on the line every cycle; drive/2 is not called", %{
      tmp_dir: dir
    } do
      {path, _uart} = line()
      {robot, _base} = start(dir, command_timeout: 5.0, wire: path)
      drive(robot, {:velocity, 0.2, 0.0})

      lines = lines(read_line(path, &(Enum.count(&1, fn l -> l == @velocity end) >= 5)))
      # before the first command the robot idles: stopped
      assert lines |> Enum.uniq() |> Enum.all?(&(&1 in ["stop", @velocity]))
      assert %{command: {:velocity, 0.2, 0.0}} = control(robot, :autonomy)
      refute match?({:ok, {:driven, _, %{command: {:velocity, _, _}}}}, driven_now(robot))
    end

    test "the E-stop puts the stop frame on the line", %{tmp_dir: dir} do
      {path, _uart} = line()
      {robot, _base} = start(dir, command_timeout: 5.0, wire: path)
      drive(robot, {:velocity, 0.2, 0.0})
      seen = read_line(path, &(@velocity in &1))

      estop(robot, true)
      assert "stop" in after_velocity(path, seen)
      control(robot, :estop)
    end

    test "the base module killed: the worker puts the fallback on the line", %{tmp_dir: dir} do
      {path, _uart} = line()
      {robot, base} = start(dir, command_timeout: 5.0, wire: path)
      :ok = Cycle.subscribe(base)
      drive(robot, {:velocity, 0.2, 0.0})
      seen = read_line(path, &(@velocity in &1))

      Process.exit(Runtime.whereis(base), :kill)
      # the activity removed: its fallback, written by the worker
      assert %{kind: :fallback, cycle: 0, wired: true} =
               ThinkingCap.Testing.Cycle.applied_until(base, &(&1.cycle == 0))

      assert ["stop" | _] = after_velocity(path, seen)
    end

    test "the node hosting the robot killed: the worker still puts the stop frame on the line",
         %{tmp_dir: dir} do
      {path, _uart} = line()
      [node] = Cluster.start(1, apps: [:tc_robot])
      on_exit(fn -> Cluster.stop(node) end)
      {robot, _base, adf} = write_adf(dir, [command_timeout: 60.0, wire: path], nil)

      assert {:ok, _} =
               Cluster.call(node, Runtime, :start, [Cluster.call(node, Config, :read!, [adf])])

      :ok =
        Cluster.call(node, Blackboard, :out, [
          {:drive, robot, %{command: {:velocity, 0.2, 0.0}}},
          [key: {:drive, robot}]
        ])

      seen = read_line(path, &(@velocity in &1))
      Cluster.kill(node)
      assert ["stop" | _] = after_velocity(path, seen)
    end
  end

  defp driven_now(robot), do: Blackboard.rdp({:driven, robot, :_})

  # a pseudo-terminal: its master here, its slave's path for the robot
  defp line do
    uart = start_supervised!(UART)
    {:ok, path} = UART.open_pty(uart)
    {path, uart}
  end

  # what the robot put on the line (all of it) once fun says enough of its lines
  defp read_line(path, fun, acc \\ "") do
    if fun.(lines(acc)) do
      acc
    else
      receive do
        {:tc_uart, ^path, data} when is_binary(data) -> read_line(path, fun, acc <> data)
      after
        5000 -> flunk("the line got only #{inspect(acc)}")
      end
    end
  end

  defp lines(bytes), do: bytes |> String.split("\n") |> Enum.drop(-1)

  # the lines after what was read already and the velocity lines still coming
  defp after_velocity(path, acc) do
    n = length(lines(acc))

    read_line(path, &(&1 |> Enum.drop(n) |> Enum.any?(fn l -> l != @velocity end)), acc)
    |> lines()
    |> Enum.drop(n)
    |> Enum.drop_while(&(&1 == @velocity))
  end
end
