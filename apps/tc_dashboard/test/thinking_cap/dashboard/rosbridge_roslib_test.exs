defmodule ThinkingCap.Dashboard.RosbridgeRoslibTest do
  # The rosbridge port with the real npm `roslib` client, in Node, and a
  # simulated robot (in the office's hall, facing along it): it lists the
  # topics, learns the ROS version, subscribes /odom, /scan, /map and /tf,
  # and drives the robot with /cmd_vel — or is refused without the token.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Dashboard, Runtime}

  @moduletag :tmp_dir
  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @script Path.expand("../../support/js/roslib_client.mjs", __DIR__)
  @token "roslib-test-token"

  setup %{tmp_dir: dir} do
    node =
      System.find_executable("node") || flunk("node is not installed (bin/setup installs it)")

    File.exists?(Path.expand("../../../assets/node_modules/roslib", __DIR__)) ||
      flunk("roslib is not installed in apps/tc_dashboard/assets (npm ci)")

    robot = :"ros#{System.unique_integer([:positive])}"
    adf = Path.join(dir, "rosbridge.adf")

    File.write!(adf, """
    [
      robot: :#{robot},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{@examples}/office.wdf",
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                         deadline: 0.005, fallback: :stop, params: [at: {6.0, 1.5, 0.0}, seed: 5]]
      ]
    ]
    """)

    {:ok, info} =
      Dashboard.start(
        port: 0,
        rosbridge_port: 0,
        token: @token,
        world: Path.join(@examples, "office.wdf")
      )

    on_exit(fn -> Dashboard.stop() end)
    {:ok, _} = Runtime.start(adf)

    # the robot leaves the simulated world with the test (a stopped base
    # stays in it, stopped, in everybody's way)
    on_exit(fn ->
      Runtime.stop(:"base_#{robot}")

      with {:ok, sim} <- ThinkingCap.Sim.Worlds.lookup("#{@examples}/office.wdf"),
           do: ThinkingCap.Sim.remove_robot(sim, robot)
    end)

    {:ok, _} = Blackboard.rd({:odom, robot, :_}, 5_000)
    {:ok, _} = Blackboard.rd({:laser, robot, :_}, 5_000)
    %{robot: robot, info: info, node: node}
  end

  defp run(ctx, query, mode) do
    url = "ws://127.0.0.1:#{ctx.info.rosbridge_port}/#{query}"

    {out, status} =
      System.cmd(ctx.node, [@script, url, "#{ctx.robot}", mode], stderr_to_stdout: true)

    assert status == 0, "the roslib client failed (#{status}):\n#{out}"

    out
    |> String.split("\n", trim: true)
    |> Enum.flat_map(fn line ->
      case :jiffy.decode(line, [:return_maps, :use_nil]) do
        %{"event" => _} = event -> [event]
        _ -> []
      end
    end)
  rescue
    e in ErlangError -> flunk("the roslib client printed something else: #{inspect(e)}")
  end

  defp event(events, name),
    do:
      Enum.find(events, &(&1["event"] == name)) || flunk("no #{name} event in #{inspect(events)}")

  defp distance(%{"x" => x0, "y" => y0}, %{"x" => x1, "y" => y1}),
    do: :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)

  test "roslib subscribes /odom, /scan, /map and /tf, publishes /cmd_vel, and the robot moves",
       ctx do
    name = Atom.to_string(ctx.robot)
    events = run(ctx, "?token=#{@token}", "drive")

    topics = event(events, "topics")
    served = Enum.zip(topics["topics"], topics["types"])
    assert {"/#{name}/odom", "nav_msgs/msg/Odometry"} in served
    assert {"/#{name}/scan", "sensor_msgs/msg/LaserScan"} in served
    assert {"/#{name}/cmd_vel", "geometry_msgs/msg/Twist"} in served
    assert {"/tf", "tf2_msgs/msg/TFMessage"} in served
    assert {"/map", "nav_msgs/msg/OccupancyGrid"} in served

    assert %{"version" => 2, "distro" => "humble"} = event(events, "ros_version")

    odom = event(events, "odom")
    assert odom["header"]["frame_id"] == "#{name}/odom"
    assert odom["child_frame_id"] == "#{name}/base_link"
    assert %{"sec" => sec, "nanosec" => ns} = odom["header"]["stamp"]
    assert is_integer(sec) and ns in 0..999_999_999

    scan = event(events, "scan")
    assert scan["header"]["frame_id"] == "#{name}/laser"
    # the office robot's laser: 181 beams over 180°
    assert scan["n"] == 181
    assert_in_delta scan["angle_min"], -1.5708, 1.0e-3

    # the office, rasterized (frame map), and where the robot is in it
    map = event(events, "map")
    assert map["header"]["frame_id"] == "map"
    assert map["n"] == map["info"]["width"] * map["info"]["height"]
    assert map["occupied"] > 0
    assert map["info"]["resolution"] == 0.05

    assert event(events, "tf")["transforms"] == [
             %{"parent" => "map", "child" => "#{name}/odom"},
             %{"parent" => "#{name}/odom", "child" => "#{name}/base_link"}
           ]

    # 1.5 s at 0.3 m/s, then the deadman stops it: about 0.5 m
    moved = event(events, "moved")
    assert distance(moved["from"], moved["to"]) > 0.2
    assert Enum.filter(events, &(&1["event"] == "status" and &1["level"] == "error")) == []

    # unadvertising handed the robot back
    assert {:ok, {:teleop, _, %{command: :release}}} = Blackboard.rdp({:teleop, ctx.robot, :_})
  end

  test "without the token roslib's /cmd_vel publishes get status errors and the robot stays",
       ctx do
    events = run(ctx, "", "denied")

    errors = for %{"event" => "status", "level" => "error", "msg" => msg} <- events, do: msg
    assert length(errors) == 15
    assert Enum.all?(errors, &(&1 =~ "needs the access token"))

    moved = event(events, "moved")
    assert distance(moved["from"], moved["to"]) < 0.001
    assert Blackboard.rdp({:teleop, ctx.robot, :_}) == :none
  end
end
