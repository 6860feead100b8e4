defmodule ThinkingCap.RobotTest do
  # Hosts robot drivers in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}
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

    adf = Config.read!(Path.join(dir, "#{robot}.adf"))
    on_exit(fn -> Runtime.stop(base) end)
    {:ok, _} = Runtime.start(adf)
    {robot, base}
  end

  defp drive(robot, command),
    do: Blackboard.out({:drive, robot, %{command: command}}, key: {:drive, robot})

  # waits for the robot to be driven with `command`
  defp driven(robot, command, timeout \\ 2000) do
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
    {robot, _base} = start(dir, command_timeout: 0.2)

    assert {:ok, {:robot, ^robot, caps}} = Blackboard.rd({:robot, robot, :_}, 1000)
    assert caps.drive == :differential
    assert caps.limits.max_speed == 0.5
    assert [%{name: :bumper, type: :bumper}] = caps.sensors

    # no command yet: stopped
    driven(robot, :stop)

    drive(robot, {:velocity, 0.2, 0.1})
    driven(robot, {:velocity, 0.2, 0.1})

    # nobody commands any more: after the timeout the robot is stopped
    t0 = System.monotonic_time(:millisecond)
    driven(robot, :stop)
    assert System.monotonic_time(:millisecond) - t0 >= 150
  end

  defp teleop(robot, command, extra \\ %{}),
    do:
      Blackboard.out({:teleop, robot, Map.merge(%{command: command}, extra)},
        key: {:teleop, robot}
      )

  defp estop(robot, engaged),
    do: Blackboard.out({:estop, robot, %{engaged: engaged}}, key: {:estop, robot})

  defp control(robot, mode, timeout \\ 2000) do
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
    {robot, _base} = start(dir, command_timeout: 5.0, teleop_timeout: 0.3)

    drive(robot, {:velocity, 0.1, 0.0})
    driven(robot, {:velocity, 0.1, 0.0})
    assert %{command: {:velocity, 0.1, 0.0}} = control(robot, :autonomy)

    teleop(robot, {:velocity, 0.4, 0.2}, %{by: "tester", sent_at: 1234.5})
    driven(robot, {:velocity, 0.4, 0.2})
    # who drives, and the client's stamp echoed back
    assert %{teleop_by: "tester", teleop_sent_at: 1234.5} = control(robot, :teleop)

    # released: autonomy's command again, at once
    teleop(robot, :release)
    driven(robot, {:velocity, 0.1, 0.0}, 250)
    control(robot, :autonomy)
  end

  test "the deadman rule: teleoperation not refreshed expires and the robot stops", %{
    tmp_dir: dir
  } do
    {robot, _base} = start(dir, teleop_timeout: 0.3)
    teleop(robot, {:velocity, 0.3, 0.0})
    driven(robot, {:velocity, 0.3, 0.0})
    t0 = System.monotonic_time(:millisecond)
    # no autonomy either: stopped once the teleoperation command is stale
    driven(robot, :stop)
    assert System.monotonic_time(:millisecond) - t0 >= 250
    control(robot, :idle)
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
end
