defmodule ThinkingCap.Dashboard.RosbridgeTest do
  # The pure parts of rosbridge: message conversions, topic names,
  # services, message definitions, the world as an occupancy grid.
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Rosbridge.{Definitions, Messages, Services, Topics, WorldMap}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @examples Path.expand("../../../../../priv/examples", __DIR__)

  defp robots(
         names,
         caps \\ %{sensors: [%{name: :laser, type: :laser}, %{name: :odom, type: :odometry}]}
       ),
       do: Map.new(names, &{&1, %{id: String.to_atom(&1), caps: caps}})

  describe "messages" do
    test "times are builtin_interfaces/Time from seconds" do
      assert Messages.time(1.25) == %{sec: 1, nanosec: 250_000_000}
      assert Messages.time(0) == %{sec: 0, nanosec: 0}
      # rounding never gives a billion nanoseconds
      assert %{sec: 3, nanosec: 0} = Messages.time(2.9999999999)
      # no stamp: the wall clock
      assert %{sec: sec} = Messages.time(nil)
      assert_in_delta sec, System.os_time(:second), 2
    end

    test "quaternions carry the yaw" do
      for yaw <- [0.0, 0.5, -2.0, 3.0] do
        q = Messages.quaternion(yaw)
        assert_in_delta q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w, 1.0, 1.0e-12
        assert_in_delta Messages.yaw(Map.new(q, fn {k, v} -> {to_string(k), v} end)), yaw, 1.0e-9
      end
    end

    test "map→odom composed with odom→base_link is the estimate" do
      for {estimate, odom} <- [
            {{2.0, 1.0, 0.3}, {0.5, -0.2, 1.0}},
            {{-3.0, 4.0, -2.5}, {1.0, 1.0, 2.8}},
            {{1.0, 1.0, 0.0}, {1.0, 1.0, 0.0}}
          ] do
        {x, y, th} = Messages.map_to_odom(estimate, odom)
        {xo, yo, tho} = odom

        composed =
          {x + :math.cos(th) * xo - :math.sin(th) * yo,
           y + :math.sin(th) * xo + :math.cos(th) * yo, th + tho}

        {ex, ey, eth} = estimate
        {cx, cy, cth} = composed
        assert_in_delta cx, ex, 1.0e-9
        assert_in_delta cy, ey, 1.0e-9
        assert_in_delta normalize_angle(cth - eth), 0.0, 1.0e-9
      end

      assert Messages.map_to_odom({1.0, 1.0, 0.0}, {1.0, 1.0, 0.0}) == {0.0, 0.0, 0.0}
    end

    test "a laser payload is a sensor_msgs/LaserScan in the sensor's frame" do
      payload = %{
        ranges: [1.0, 2, nil],
        angle_min: -1.5,
        angle_max: 1.5,
        angle_increment: 1.5,
        range_min: 0.1,
        range_max: 8.0,
        stamp: 12.5
      }

      scan = Messages.laser_scan(payload, "r1/laser")
      assert scan.header == %{stamp: %{sec: 12, nanosec: 500_000_000}, frame_id: "r1/laser"}
      assert scan.ranges == [1.0, 2.0, nil]
      assert {scan.angle_min, scan.angle_max, scan.angle_increment} == {-1.5, 1.5, 1.5}
      assert {scan.range_min, scan.range_max} == {0.1, 8.0}
      assert scan.intensities == []
    end

    test "odometry is a nav_msgs/Odometry from odom to base_link" do
      odom =
        Messages.odometry(
          %{pose: {1.0, 2.0, :math.pi() / 2}, twist: {0.3, -0.1}, stamp: 3.0},
          "r1"
        )

      assert odom.header.frame_id == "r1/odom"
      assert odom.child_frame_id == "r1/base_link"
      assert odom.pose.pose.position == %{x: 1.0, y: 2.0, z: 0.0}
      assert_in_delta odom.pose.pose.orientation.z, :math.sqrt(0.5), 1.0e-12
      assert odom.twist.twist.linear.x == 0.3
      assert odom.twist.twist.angular.z == -0.1
      assert length(odom.pose.covariance) == 36
    end

    test "the estimate's 3×3 covariance lands on x, y and yaw of the 6×6" do
      cov = Messages.covariance6([[1, 2, 3], [4, 5, 6], [7, 8, 9]])
      at = fn i, j -> Enum.at(cov, i * 6 + j) end
      assert {at.(0, 0), at.(0, 1), at.(0, 5)} == {1.0, 2.0, 3.0}
      assert {at.(1, 0), at.(1, 1), at.(1, 5)} == {4.0, 5.0, 6.0}
      assert {at.(5, 0), at.(5, 1), at.(5, 5)} == {7.0, 8.0, 9.0}
      assert Enum.sum(cov) == 45.0
      assert Messages.covariance6(nil) == List.duplicate(0.0, 36)
    end

    test "a Twist gives linear.x and angular.z; missing fields are 0; anything else is refused" do
      assert Messages.from_twist(%{"linear" => %{"x" => 0.2}, "angular" => %{"z" => -1}}) ==
               {:ok, {0.2, -1.0}}

      assert Messages.from_twist(%{}) == {:ok, {0.0, 0.0}}

      assert {:error, "linear.x must be a number" <> _} =
               Messages.from_twist(%{"linear" => %{"x" => "fast"}})

      assert {:error, "angular must be" <> _} = Messages.from_twist(%{"angular" => [1, 2, 3]})
      assert {:error, _} = Messages.from_twist("forward")
      assert {:error, _} = Messages.from_twist(nil)
    end

    test "/tf has map→odom and odom→base_link; identity without an estimate, nothing without odometry" do
      odom = %{pose: {1.0, 0.0, 0.0}, stamp: 1.0}
      [map_odom, odom_base] = Messages.robot_transforms("r1", odom, nil)
      assert {map_odom.header.frame_id, map_odom.child_frame_id} == {"map", "r1/odom"}
      assert map_odom.transform.translation == %{x: 0.0, y: 0.0, z: 0.0}
      assert {odom_base.header.frame_id, odom_base.child_frame_id} == {"r1/odom", "r1/base_link"}
      assert odom_base.transform.translation.x == 1.0

      [map_odom, _] = Messages.robot_transforms("r1", odom, %{pose: {3.0, 1.0, 0.0}})
      assert map_odom.transform.translation == %{x: 2.0, y: 1.0, z: 0.0}

      assert Messages.robot_transforms("r1", nil, %{pose: {3.0, 1.0, 0.0}}) == []
    end

    test "/tf_static places the sensors with a pose on base_link" do
      caps = %{
        sensors: [
          %{name: :front, type: :laser, pose: {0.2, 0.0, 0.0}},
          %{name: :rear, type: :laser},
          %{name: :sonar, type: :sonar, count: 8},
          %{name: :odom, type: :odometry}
        ]
      }

      transforms = Messages.static_transforms("r1", caps)
      assert Enum.map(transforms, & &1.child_frame_id) == ["r1/front", "r1/rear"]
      assert Enum.all?(transforms, &(&1.header.frame_id == "r1/base_link"))
      assert hd(transforms).transform.translation.x == 0.2
    end

    test "an occupancy grid keeps its cells' signed bytes, bottom row first" do
      grid =
        Messages.occupancy_grid(%{
          width: 2,
          height: 2,
          resolution: 0.5,
          origin: {-1.0, -2.0, 0.0},
          data: <<-1::signed-8, 0, 100, 50>>
        })

      assert grid.data == [-1, 0, 100, 50]
      assert grid.header.frame_id == "map"
      assert grid.info.width == 2 and grid.info.height == 2 and grid.info.resolution == 0.5
      assert grid.info.origin.position == %{x: -1.0, y: -2.0, z: 0.0}
    end
  end

  describe "topics" do
    test "namespaced names resolve to their robot, with or without the leading slash" do
      assert {:ok, %{kind: :odom, robot: "r1", type: "nav_msgs/msg/Odometry", name: "/r1/odom"}} =
               Topics.resolve("/r1/odom", %{})

      assert {:ok, %{kind: :scan, robot: "r2", name: "/r2/scan"}} = Topics.resolve("r2/scan", %{})
      assert {:ok, %{kind: :tf, robot: nil}} = Topics.resolve("/tf", robots(["r1", "r2"]))
      assert {:ok, %{kind: :map, robot: nil}} = Topics.resolve("/map", %{})
    end

    test "un-namespaced aliases name the only robot, and are refused otherwise" do
      assert {:ok, %{kind: :cmd_vel, robot: "r1", name: "/cmd_vel"}} =
               Topics.resolve("/cmd_vel", robots(["r1"]))

      assert {:error, "/odom is ambiguous with 2 robots; use a namespace, as in /r1/odom"} =
               Topics.resolve("/odom", robots(["r2", "r1"]))

      assert {:error, "/scan: no robot is known yet" <> _} = Topics.resolve("/scan", %{})
    end

    test "unknown and malformed names are refused" do
      for name <- ["/r1/joint_states", "/", "", "/r1/odom/", "/a/b/c", "/r-1/odom", "/1r/odom"] do
        assert {:error, _} = Topics.resolve(name, robots(["r1"])), "#{inspect(name)} was accepted"
      end

      assert {:error, "a topic is required"} = Topics.resolve(nil, %{})
      assert {:error, "a topic name is a string" <> _} = Topics.resolve(42, %{})

      assert {:error, "topic name too long"} =
               Topics.resolve("/" <> String.duplicate("a", 300), %{})
    end

    test "types match with or without /msg/" do
      {:ok, topic} = Topics.resolve("/r1/cmd_vel", %{})
      assert Topics.type_matches?(topic, "geometry_msgs/Twist")
      assert Topics.type_matches?(topic, "geometry_msgs/msg/Twist")
      assert Topics.type_matches?(topic, nil)
      refute Topics.type_matches?(topic, "geometry_msgs/TwistStamped")
      refute Topics.type_matches?(topic, 7)
    end

    test "the list has every robot's topics, /map with a world, aliases with one robot" do
      one = Topics.list(robots(["r1"]), true)
      names = Enum.map(one, &elem(&1, 0))
      assert {"/r1/scan", "sensor_msgs/msg/LaserScan"} in one
      assert {"/map", "nav_msgs/msg/OccupancyGrid"} in one
      assert Enum.all?(~w(/scan /odom /pose /amcl_pose /cmd_vel /tf /tf_static), &(&1 in names))
      assert {"/r1/map", "nav_msgs/msg/OccupancyGrid"} in one
      assert names == Enum.sort(names)

      two = Topics.list(robots(["r1", "r2"]), false) |> Enum.map(&elem(&1, 0))
      assert "/r2/odom" in two and "/r1/odom" in two
      refute "/odom" in two
      refute "/map" in two

      # a robot without a laser has no scan
      bare = Topics.list(robots(["r3"], %{sensors: []}), false) |> Enum.map(&elem(&1, 0))
      refute "/r3/scan" in bare
      refute "/r3/odom" in bare
      assert "/r3/cmd_vel" in bare
    end

    test "a robot's laser and odometry are read from the tags its capabilities name" do
      caps = %{sensors: [%{name: :front, type: :laser}, %{name: :wheels, type: :odometry}]}
      rs = robots(["r1"], caps)
      {:ok, scan} = Topics.resolve("/r1/scan", rs)
      assert Topics.tags(scan, rs) == [:front]
      assert Topics.feeds?(scan, :front, "r1", rs)
      refute Topics.feeds?(scan, :front, "r2", rs)
      refute Topics.feeds?(scan, :laser, "r1", rs)
      {:ok, tf} = Topics.resolve("/tf", rs)
      assert :wheels in Topics.tags(tf, rs) and :pose in Topics.tags(tf, rs)
      assert Topics.feeds?(tf, :wheels, "r1", rs)
    end
  end

  describe "services" do
    @topics [{"/map", "nav_msgs/msg/OccupancyGrid"}, {"/r1/odom", "nav_msgs/msg/Odometry"}]

    test "rosapi lists the topics and their types" do
      assert Services.call("/rosapi/topics", %{}, @topics) ==
               {:ok,
                %{
                  topics: ["/map", "/r1/odom"],
                  types: ["nav_msgs/msg/OccupancyGrid", "nav_msgs/msg/Odometry"]
                }}

      assert Services.call("/rosapi/topics_for_type", %{"type" => "nav_msgs/Odometry"}, @topics) ==
               {:ok, %{topics: ["/r1/odom"]}}

      assert Services.call("/rosapi/topic_type", ["r1/odom"], @topics) ==
               {:ok, %{type: "nav_msgs/msg/Odometry"}}

      assert Services.call("/rosapi/topic_type", %{"topic" => "/nope"}, @topics) ==
               {:ok, %{type: ""}}

      {:ok, raw} = Services.call("/rosapi/topics_and_raw_types", nil, @topics)
      assert [grid, odom] = raw.typedefs_full_text
      assert grid =~ "MSG: nav_msgs/MapMetaData"
      assert odom =~ "MSG: geometry_msgs/TwistWithCovariance"
    end

    test "it says ROS 2 humble" do
      assert Services.call("/rosapi/get_ros_version", %{}, []) ==
               {:ok, %{version: 2, distro: "humble"}}

      assert {:ok, %{services: services}} = Services.call("/rosapi/services", %{}, [])
      assert "/rosapi/topics" in services
    end

    test "unknown services and bad arguments are errors" do
      assert {:error, "Service /add_two_ints does not exist"} =
               Services.call("/add_two_ints", %{}, [])

      assert {:error, "argument type is required"} =
               Services.call("/rosapi/topics_for_type", %{}, [])

      assert {:error, "argument type must be a string" <> _} =
               Services.call("/rosapi/topics_for_type", %{"type" => 1}, [])

      assert {:error, "service arguments must be an object" <> _} =
               Services.call("/rosapi/topics", "x", [])

      assert {:error, _} = Services.call("/rosapi/topic_type", [1, 2, 3], [])
    end
  end

  describe "definitions" do
    test "a full text is the type then each type it uses, once" do
      text = Definitions.full_text("nav_msgs/msg/Odometry")
      [main | parts] = String.split(text, String.duplicate("=", 80) <> "\n")
      assert main =~ ~r/^std_msgs\/Header header\n/
      names = Enum.map(parts, fn "MSG: " <> rest -> rest |> String.split("\n") |> hd() end)
      assert Enum.sort(names) == Enum.sort(Enum.uniq(names))

      assert Enum.sort(names) ==
               Enum.sort(
                 ~w(std_msgs/Header builtin_interfaces/Time geometry_msgs/PoseWithCovariance
                 geometry_msgs/Pose geometry_msgs/Point geometry_msgs/Quaternion
                 geometry_msgs/TwistWithCovariance geometry_msgs/Twist geometry_msgs/Vector3)
               )

      assert Definitions.full_text("geometry_msgs/Twist") ==
               "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n" <>
                 String.duplicate("=", 80) <>
                 "\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"

      assert Definitions.full_text("std_msgs/String") == nil
    end

    test "every served type has a definition" do
      for {_name, type} <-
            Topics.list(
              %{"r1" => %{id: :r1, caps: %{sensors: [%{type: :laser}, %{type: :odometry}]}}},
              true
            ) do
        assert Definitions.known?(type), type
      end
    end
  end

  describe "the world as a map" do
    test "a WDF without a grid is rasterized: walls occupied, rooms free" do
      assert {:ok, cells} = WorldMap.cells(Path.join(@examples, "office.wdf"))
      assert byte_size(cells.data) == cells.width * cells.height
      values = cells.data |> :binary.bin_to_list() |> Enum.uniq() |> Enum.sort()
      assert values == [0, 100]
      assert cells.resolution == 0.05
      {ox, oy, 0.0} = cells.origin
      assert is_float(ox) and is_float(oy)
    end

    test "a WDF importing a ROS map gives that map's cells", %{} do
      dir = Path.join(System.tmp_dir!(), "rosbridge_map_#{System.unique_integer([:positive])}")
      File.mkdir_p!(dir)
      # 2×2: black (occupied), white (free) on top; grey (unknown), white below
      File.write!(Path.join(dir, "m.pgm"), "P5\n2 2\n255\n" <> <<0, 255, 128, 255>>)

      File.write!(Path.join(dir, "m.yaml"), """
      image: m.pgm
      resolution: 0.5
      origin: [-1.0, -1.0, 0.0]
      negate: 0
      occupied_thresh: 0.65
      free_thresh: 0.196
      """)

      File.write!(Path.join(dir, "w.wdf"), ~s([name: "m", map: [yaml: "m.yaml"]]\n))
      on_exit(fn -> File.rm_rf!(dir) end)

      assert {:ok, cells} = WorldMap.cells(Path.join(dir, "w.wdf"))
      assert {cells.width, cells.height, cells.resolution} == {2, 2, 0.5}
      # bottom row first
      assert for(<<v::signed-8 <- cells.data>>, do: v) == [-1, 0, 100, 0]
    end

    test "no world, or a broken one, is an error" do
      assert {:error, "the dashboard has no world" <> _} = WorldMap.cells(nil)
      assert {:error, "the world could not be read" <> _} = WorldMap.cells("/nonexistent/x.wdf")
      assert {:error, _} = WorldMap.cells(42)
    end
  end
end
