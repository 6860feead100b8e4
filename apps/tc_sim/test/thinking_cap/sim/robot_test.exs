defmodule ThinkingCap.Sim.RobotTest do
  # Hosts robots in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.Testing.Robot, as: TestRobot
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir

  @laser [name: :laser, type: :laser, range: {0.05, 8.0}, fov: 3.14, beams: 61, rate: 10]

  # The same ADF text, but for the base's module: line.
  defp adf(dir, robot, base_module) do
    wdf = T.wdf!(dir, walls: T.box(10, 10), waypoints: [[name: :start, at: {2, 5, 0}]])
    rdf = T.rdf!(dir, sensors: [@laser, [name: :bumper, type: :bumper, rate: 10]])
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: #{inspect(rdf)},
      wdf: #{inspect(wdf)},
      modules: [
        base_#{robot}: [module: #{inspect(base_module)}, activity: :periodic, period: 0.01,
                        deadline: 0.005, fallback: :stop, params: [at: :start]],
        wander_#{robot}: [module: ThinkingCap.Sim.Wanderer, activity: :event,
                          subscribe: [{:laser, :#{robot}, :_}, {:bumper, :#{robot}, :_}]]
      ]
    ]
    """)

    adf = Config.read!(path)
    on_exit(fn -> for m <- adf.modules, do: Runtime.stop(m.name) end)
    adf
  end

  defp wait_until(fun, timeout \\ 5000) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      Process.sleep(20)
      fun.()
    end)
    |> Enum.find(fn result -> result || System.monotonic_time(:millisecond) > deadline end)
  end

  test "the same ADF drives the simulated robot or a real one; only module: differs", %{
    tmp_dir: dir
  } do
    # simulated: the robot appears in the world, scans it, wanders away from its start
    sim_robot = :"s#{System.unique_integer([:positive])}"
    {:ok, _} = Runtime.start(adf(dir, sim_robot, ThinkingCap.Sim.Robot))

    assert {:ok, {:laser, ^sim_robot, scan}} = Blackboard.rd({:laser, sim_robot, :_}, 3000)
    # straight ahead from (2, 5) facing east: the wall 8 m away is at max range
    assert length(scan.ranges) == 61

    assert {:ok, {:robot, ^sim_robot, %{drive: :differential}}} =
             Blackboard.rd({:robot, sim_robot, :_}, 1000)

    moved =
      wait_until(fn ->
        case Blackboard.rdp({:sim_pose, sim_robot, :_}) do
          {:ok, {_, _, %{pose: {x, _, _}}}} -> x > 2.3
          _ -> false
        end
      end)

    assert moved,
           "the simulated robot did not wander off: #{inspect(Blackboard.rdp({:sim_pose, sim_robot, :_}))}"

    # "real": the same modules; the wanderer's commands reach the driver
    real_robot = :"h#{System.unique_integer([:positive])}"
    {:ok, _} = Runtime.start(adf(dir, real_robot, ThinkingCap.Testing.Robot))
    free = Enum.map(1..61, fn _ -> 5.0 end)
    scan = %{ranges: free, angle_min: -1.57, angle_increment: 3.14 / 60, stamp: 0.0}
    TestRobot.feed(:"base_#{real_robot}", [{:laser, scan}])

    driven =
      wait_until(fn ->
        case Blackboard.rdp({:driven, real_robot, :_}) do
          {:ok, {_, _, %{command: {:velocity, v, _}}}} when v > 0 -> true
          _ -> false
        end
      end)

    assert driven
    # and the simulated world knows nothing of it
    {:ok, sim} =
      ThinkingCap.Sim.Worlds.lookup(Config.read!(Path.join(dir, "#{sim_robot}.adf")).wdf)

    assert Map.keys(ThinkingCap.Sim.robots(sim)) == [sim_robot]
  end

  test "a simulated robot whose driver stops is left stopped in the world", %{tmp_dir: dir} do
    robot = :"s#{System.unique_integer([:positive])}"
    adf = adf(dir, robot, ThinkingCap.Sim.Robot)
    {:ok, _} = Runtime.start(adf)
    {:ok, sim} = ThinkingCap.Sim.Worlds.lookup(adf.wdf)

    assert wait_until(fn ->
             match?({:ok, {x, _, _}} when x > 2.2, ThinkingCap.Sim.pose(sim, robot))
           end)

    # the wanderer still commands it: the stopped driver has stopped the robot
    :ok = Runtime.stop(:"base_#{robot}")
    # braking takes a few steps
    Process.sleep(100)
    {:ok, p1} = ThinkingCap.Sim.pose(sim, robot)
    Process.sleep(200)
    assert {:ok, ^p1} = ThinkingCap.Sim.pose(sim, robot)
  end
end
