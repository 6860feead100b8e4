defmodule ThinkingCap.Dashboard.RosbridgeSessionTest do
  # A rosbridge session driven directly (no socket): client messages in,
  # blackboard tuples of made-up robots in, frames out.
  use ExUnit.Case, async: false

  import ThinkingCap.Dashboard.Test.Rosbridge

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Rosbridge.Session

  @examples Path.expand("../../../../../priv/examples", __DIR__)

  defp odom(robot, x, stamp),
    do: out({:odom, robot, %{pose: {x, 0.0, 0.0}, twist: {0.1, 0.0}, stamp: stamp}})

  defp teleop(robot) do
    case Blackboard.rdp({:teleop, robot, :_}) do
      {:ok, {:teleop, ^robot, payload}} -> payload
      :none -> nil
    end
  end

  describe "subscribe" do
    test "a subscription gets the latest value at once, then every new one" do
      robot = robot!()
      odom(robot, 1.0, 1.0)
      s = open()

      {frames, s} =
        send_msg(s, %{
          op: "subscribe",
          id: "s1",
          topic: "/#{robot}/odom",
          type: "nav_msgs/Odometry"
        })

      assert [msg] = published(frames, "/#{robot}/odom")
      assert msg["pose"]["pose"]["position"]["x"] == 1.0
      assert msg["header"]["frame_id"] == "#{robot}/odom"

      odom(robot, 2.0, 2.0)
      {frames, _s} = deliver_until(s, &(&1["op"] == "publish"))
      assert [msg] = published(frames, "/#{robot}/odom")
      assert msg["pose"]["pose"]["position"]["x"] == 2.0
      assert msg["header"]["stamp"] == %{"sec" => 2, "nanosec" => 0}
    end

    test "a robot's scan comes from the laser its capabilities name, in that sensor's frame" do
      robot = robot!()
      s = open()
      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{robot}/scan"})

      out({:laser, robot, %{ranges: [9.0], stamp: 0.5}})

      out(
        {:lidar, robot,
         %{ranges: [1.0, 2.0], angle_min: -0.5, angle_max: 0.5, angle_increment: 1.0, stamp: 1.0}}
      )

      {frames, _s} = deliver_until(s, &(&1["op"] == "publish"))
      assert [scan] = published(frames, "/#{robot}/scan")
      assert scan["ranges"] == [1.0, 2.0]
      assert scan["header"]["frame_id"] == "#{robot}/lidar"
    end

    test "a throttled subscription sends the first message, then only the newest held back" do
      robot = robot!()
      s = open()
      topic = "/#{robot}/odom"
      {[], s} = send_msg(s, %{op: "subscribe", id: "t", topic: topic, throttle_rate: 60_000})

      odom(robot, 1.0, 1.0)
      {frames, s} = deliver_until(s, &(&1["op"] == "publish"))
      assert [%{"pose" => %{"pose" => %{"position" => %{"x" => 1.0}}}}] = published(frames, topic)

      odom(robot, 2.0, 2.0)
      odom(robot, 3.0, 3.0)
      {frames, s} = deliver_waiting(s)
      assert published(frames, topic) == []

      # the throttle's timer fires: the newest one goes
      robot_name = Atom.to_string(robot)
      assert %{timers: %{^robot_name => _}} = s.subs[topic]

      {frames, s} =
        result(Session.handle_info({:rosbridge_flush, topic, Atom.to_string(robot)}, s))

      assert [%{"pose" => %{"pose" => %{"position" => %{"x" => 3.0}}}}] = published(frames, topic)
      assert s.subs[topic].pending == %{}
    end

    test "unsubscribing stops the messages and the blackboard subscription" do
      robot = robot!()
      s = open()
      topic = "/#{robot}/odom"
      {[], s} = send_msg(s, %{op: "subscribe", id: "a", topic: topic})
      {[], s} = send_msg(s, %{op: "subscribe", id: "b", topic: topic})
      assert Map.has_key?(s.tags, :odom)

      # an id it does not know: nothing changes (a warning says so)
      {[], s} = send_msg(s, %{op: "set_level", level: "warning"})

      assert {[%{"level" => "warning", "msg" => "unsubscribe: no subscription \"z\"" <> _}], ^s} =
               send_msg(s, %{op: "unsubscribe", id: "z", topic: topic})

      # one of two ids: still subscribed
      {[], s} = send_msg(s, %{op: "unsubscribe", id: "a", topic: topic})
      odom(robot, 1.0, 1.0)
      {frames, s} = deliver_until(s, &(&1["op"] == "publish"))
      assert [_] = published(frames, topic)

      {[], s} = send_msg(s, %{op: "unsubscribe", id: "b", topic: topic})
      refute Map.has_key?(s.tags, :odom)
      assert s.subs == %{}
      odom(robot, 2.0, 2.0)
      assert {[], _} = deliver_waiting(s)
    end

    test "a robot's topic may be subscribed before the robot appears" do
      s = open()
      name = "rblate#{System.unique_integer([:positive])}"
      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{name}/odom"})
      robot = String.to_atom(name)
      on_exit(fn -> for tag <- [:odom], do: Blackboard.takep({tag, robot, :_}) end)
      odom(robot, 4.0, 1.0)
      {frames, _s} = deliver_until(s, &(&1["op"] == "publish"))

      assert [%{"pose" => %{"pose" => %{"position" => %{"x" => 4.0}}}}] =
               published(frames, "/#{name}/odom")
    end

    test "bad subscriptions get a status error with their id, and change nothing" do
      robot = robot!()
      s = open()

      for {message, text} <- [
            {%{op: "subscribe", id: 1, topic: "/#{robot}/odom", type: "sensor_msgs/LaserScan"},
             "is a nav_msgs/msg/Odometry"},
            {%{op: "subscribe", id: 1, topic: "/#{robot}/joints"}, "unknown topic"},
            {%{op: "subscribe", id: 1}, "a topic is required"},
            {%{op: "subscribe", id: 1, topic: ["/odom"]}, "a topic name is a string"},
            {%{op: "subscribe", id: 1, topic: "/#{robot}/odom", throttle_rate: -5},
             "throttle_rate"},
            {%{op: "subscribe", id: 1, topic: "/#{robot}/odom", throttle_rate: "fast"},
             "throttle_rate"},
            {%{op: "subscribe", id: 1, topic: "/map"}, "no world"}
          ] do
        assert {[%{"op" => "status", "level" => "error", "id" => 1, "msg" => msg}], ^s} =
                 send_msg(s, message)

        assert msg =~ text
      end
    end

    test "compression is refused with a warning (when warnings are asked for), messages come as JSON" do
      robot = robot!()
      odom(robot, 1.0, 1.0)
      s = open()
      {[], s} = send_msg(s, %{op: "set_level", level: "warning"})

      {frames, _s} =
        send_msg(s, %{op: "subscribe", id: "c", topic: "/#{robot}/odom", compression: "cbor"})

      assert [%{"msg" => "subscribe: compression \"cbor\" is not supported" <> _, "id" => "c"}] =
               statuses(frames, "warning")

      assert [_] = published(frames, "/#{robot}/odom")
    end

    test "the number of subscriptions is bounded" do
      robot = robot!()
      s = open()

      s =
        Enum.reduce(1..256, s, fn i, s ->
          {[], s} = send_msg(s, %{op: "subscribe", id: "x#{i}", topic: "/#{robot}/pose"})
          s
        end)

      assert {[%{"msg" => "subscribe: too many" <> _}], _} =
               send_msg(s, %{op: "subscribe", id: "one more", topic: "/#{robot}/pose"})

      # an id already there may subscribe again
      assert {[], _} = send_msg(s, %{op: "subscribe", id: "x1", topic: "/#{robot}/pose"})
    end
  end

  describe "tf, pose and map" do
    test "/tf places odom in the map from the estimate and base_link in odom" do
      robot = robot!()
      name = Atom.to_string(robot)
      odom(robot, 1.0, 5.0)

      out(
        {:pose, robot,
         %{
           pose: {3.0, 2.0, 0.0},
           covariance: [[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.01]],
           stamp: 5.0
         }}
      )

      s = open()

      {frames, s} = send_msg(s, %{op: "subscribe", topic: "/tf"})

      [%{"transforms" => transforms} | _] =
        published(frames, "/tf") |> Enum.filter(&mine?(&1, name))

      by_child = Map.new(transforms, &{&1["child_frame_id"], &1})
      map_odom = by_child["#{name}/odom"]
      assert map_odom["header"]["frame_id"] == "map"
      assert map_odom["transform"]["translation"] == %{"x" => 2.0, "y" => 2.0, "z" => 0.0}
      assert by_child["#{name}/base_link"]["transform"]["translation"]["x"] == 1.0

      # the robot moves on its odometry; the estimate is unchanged
      odom(robot, 1.5, 5.1)
      {frames, _s} = deliver_until(s, &(&1["op"] == "publish" and mine?(&1["msg"], name)))
      [%{"transforms" => transforms}] = published(frames, "/tf") |> Enum.filter(&mine?(&1, name))
      by_child = Map.new(transforms, &{&1["child_frame_id"], &1})
      assert by_child["#{name}/odom"]["transform"]["translation"]["x"] == 1.5
      assert by_child["#{name}/base_link"]["transform"]["translation"]["x"] == 1.5
    end

    test "/tf_static places the laser on base_link; /r1/pose is the estimate in map" do
      robot = robot!()
      name = Atom.to_string(robot)
      s = open()
      {frames, s} = send_msg(s, %{op: "subscribe", topic: "/#{name}/tf_static"})
      assert [%{"transforms" => [laser]}] = published(frames, "/#{name}/tf_static")
      assert laser["child_frame_id"] == "#{name}/lidar"
      assert laser["header"]["frame_id"] == "#{name}/base_link"
      assert laser["transform"]["translation"]["x"] == 0.1

      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{name}/pose"})

      out(
        {:pose, robot,
         %{pose: {3.0, 2.0, 1.0}, covariance: [[0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.3]], stamp: 1.0}}
      )

      {frames, _s} = deliver_until(s, &(&1["op"] == "publish"))
      assert [pose] = published(frames, "/#{name}/pose")
      assert pose["header"]["frame_id"] == "map"
      assert Enum.at(pose["pose"]["covariance"], 35) == 0.3
    end

    test "/r1/map and /map carry the map the robot learned; /amcl_pose its estimate" do
      robot = robot!()
      name = Atom.to_string(robot)
      s = open()
      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{name}/map"})
      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{name}/amcl_pose"})

      grid = %ThinkingCap.Navigation.OccupancyGrid{
        width: 3,
        height: 2,
        data: <<0, 100, -1::signed-8, 0, 0, 50>>,
        resolution: 0.1,
        origin: {1.0, 2.0},
        version: 4
      }

      out({:map, robot, grid})
      {frames, s} = deliver_until(s, &(&1["topic"] == "/#{name}/map"))
      assert [msg] = published(frames, "/#{name}/map")
      assert msg["data"] == [0, 100, -1, 0, 0, 50]
      assert {msg["info"]["width"], msg["info"]["height"]} == {3, 2}
      assert msg["info"]["origin"]["position"]["x"] == 1.0
      assert msg["header"]["frame_id"] == "map"

      out(
        {:pose, robot,
         %{pose: {3.0, 2.0, 1.0}, covariance: [[0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.3]], stamp: 1.0}}
      )

      {frames, _s} = deliver_until(s, &(&1["topic"] == "/#{name}/amcl_pose"))
      assert [pose] = published(frames, "/#{name}/amcl_pose")
      assert pose["pose"]["pose"]["position"]["x"] == 3.0

      # a new subscriber of /map gets the learned map at once, not the world's
      s2 = open(world: Path.join(@examples, "office.wdf"))
      {frames, _} = map_request(s2, %{op: "subscribe", topic: "/map"})
      assert Enum.any?(published(frames, "/map"), &(&1["data"] == [0, 100, -1, 0, 0, 50]))
      Blackboard.takep({:map, robot, :_})
    end

    test "/map is the world's occupancy grid" do
      s = open(world: Path.join(@examples, "office.wdf"))

      {frames, _s} =
        map_request(s, %{op: "subscribe", topic: "/map", type: "nav_msgs/msg/OccupancyGrid"})

      assert [grid] = published(frames, "/map")
      assert grid["info"]["width"] * grid["info"]["height"] == length(grid["data"])
      assert grid["header"]["frame_id"] == "map"
      assert 100 in grid["data"] and 0 in grid["data"]
    end

    test "maps sent are bounded per node: a burst of re-subscribes gets status errors" do
      s = open(world: Path.join(@examples, "office.wdf"))
      # past the current second's sends, whoever made them
      Process.sleep(1_000 - rem(System.monotonic_time(:millisecond), 1_000))

      started = System.monotonic_time(:millisecond)

      {sent, refused} =
        Enum.reduce(1..30, {0, 0}, fn i, {sent, refused} ->
          message = %{op: "subscribe", id: "m#{i}", topic: "/map"}
          {frames, _s} = send_msg(s, message)

          cond do
            published(frames, "/map") != [] -> {sent + 1, refused}
            Enum.any?(frames, &(&1["msg"] =~ "too many map requests")) -> {sent, refused + 1}
          end
        end)

      # at most 10 a second: a loaded machine may spread the burst over
      # more than one
      seconds = div(System.monotonic_time(:millisecond) - started, 1_000) + 1
      assert sent >= 1 and sent <= 10 * seconds
      assert refused >= 1
      assert sent + refused == 30
      # the next test starts with this node's budget back
      Process.sleep(1_000 - rem(System.monotonic_time(:millisecond), 1_000))
    end
  end

  describe "cmd_vel" do
    test "without the token a publish is refused and does nothing" do
      robot = robot!()
      s = open()
      topic = "/#{robot}/cmd_vel"

      {[], s} =
        send_msg(s, %{op: "advertise", id: "a", topic: topic, type: "geometry_msgs/msg/Twist"})

      assert {[%{"op" => "status", "level" => "error", "id" => "p", "msg" => msg}], _} =
               send_msg(s, %{op: "publish", id: "p", topic: topic, msg: %{linear: %{x: 0.2}}})

      assert msg =~ "needs the access token"
      assert teleop(robot) == nil
    end

    test "with the token in the URL a publish drives the robot, clamped to its limits" do
      robot = robot!()
      s = open(control: true)
      topic = "/#{robot}/cmd_vel"

      assert {[], s} =
               send_msg(s, %{
                 op: "publish",
                 topic: topic,
                 msg: %{linear: %{x: 2.0}, angular: %{z: -0.5}}
               })

      assert %{command: {:velocity, 0.5, -0.5}, by: "rosbridge 127.0.0.1:40000"} = teleop(robot)

      # unadvertising hands the robot back
      {[], s} = send_msg(s, %{op: "advertise", topic: topic, type: "geometry_msgs/Twist"})
      {[], _s} = send_msg(s, %{op: "unadvertise", topic: topic})
      assert %{command: :release} = teleop(robot)
    end

    test "the auth op grants control; wrong tokens are refused and five close the connection" do
      robot = robot!()
      s = open()
      publish = %{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{linear: %{x: 0.1}}}

      {[%{"level" => "error", "msg" => "auth: the mac is not the access token"}], s} =
        send_msg(s, %{
          op: "auth",
          mac: "wrong",
          client: "c",
          dest: "d",
          rand: "r",
          t: 0,
          level: "admin",
          end: 0
        })

      {[%{"level" => "error"}], s} = send_msg(s, publish)
      assert teleop(robot) == nil

      {[], s} = send_msg(s, %{op: "auth", mac: token()})
      {[], s} = send_msg(s, publish)
      assert %{command: {:velocity, 0.1, +0.0}} = teleop(robot)

      s = %{s | control: false}

      s =
        Enum.reduce(1..4, s, fn _, s ->
          {[%{"level" => "error"}], s} = send_msg(s, %{op: "auth", mac: 12})
          s
        end)

      assert {:close, _} = send_msg(s, %{op: "auth", mac: "still wrong"})
    end

    test "closing the connection hands back a robot it drives, not one someone else took" do
      robot = robot!()
      other = robot!()
      s = open(control: true)

      {[], s} =
        send_msg(s, %{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{linear: %{x: 0.1}}})

      {[], s} =
        send_msg(s, %{op: "publish", topic: "/#{other}/cmd_vel", msg: %{linear: %{x: 0.1}}})

      ThinkingCap.Dashboard.Control.teleop(other, 0.2, 0.0, by: "page 10.0.0.1:1")
      Session.terminate(:normal, s)
      assert %{command: :release} = teleop(robot)
      assert %{command: {:velocity, 0.2, 0.0}, by: "page 10.0.0.1:1"} = teleop(other)
    end

    test "bad publishes are refused: other topics, unknown robots, malformed twists" do
      robot = robot!()
      s = open(control: true)

      for {message, text} <- [
            {%{op: "publish", topic: "/#{robot}/odom", msg: %{}}, "published by this server"},
            {%{
               op: "publish",
               topic: "/ghost#{System.unique_integer([:positive])}/cmd_vel",
               msg: %{}
             }, "no robot"},
            {%{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{linear: %{x: "1"}}},
             "linear.x must be a number"},
            {%{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{angular: %{z: -1.0e300}}},
             "angular.z must be a number from -100"},
            {%{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{linear: %{x: 10 ** 5000}}},
             "linear.x must be a number from -100"},
            {%{op: "publish", topic: "/#{robot}/cmd_vel", msg: [0.1, 0.0]}, "is an object"},
            {%{op: "publish", topic: "/#{robot}/cmd_vel"}, "is an object"},
            {%{op: "advertise", topic: "/#{robot}/cmd_vel", type: "std_msgs/String"},
             "is a geometry_msgs/msg/Twist"},
            {%{op: "advertise", topic: "/#{robot}/cmd_vel"}, "a type is required"},
            {%{op: "advertise", topic: "/#{robot}/scan", type: "sensor_msgs/LaserScan"},
             "published by this server"}
          ] do
        assert {[%{"op" => "status", "level" => "error", "msg" => msg}], _} = send_msg(s, message)
        assert msg =~ text
      end

      assert teleop(robot) == nil
    end

    test "subscribing to cmd_vel shows the command the base applies" do
      robot = robot!()
      s = open()
      {[], s} = send_msg(s, %{op: "subscribe", topic: "/#{robot}/cmd_vel"})
      out({:control, robot, %{mode: :teleop, command: {:velocity, 0.3, 0.1}}})
      {frames, _s} = deliver_until(s, &(&1["op"] == "publish"))

      assert [%{"linear" => %{"x" => 0.3}, "angular" => %{"z" => 0.1}}] =
               published(frames, "/#{robot}/cmd_vel")
    end
  end

  describe "services and other ops" do
    test "rosapi lists the robot's topics and says ROS 2" do
      robot = robot!()
      s = open(world: Path.join(@examples, "office.wdf"))

      {[resp], s} =
        send_msg(s, %{op: "call_service", id: "call:1", service: "rosapi/topics", args: %{}})

      assert %{
               "op" => "service_response",
               "id" => "call:1",
               "result" => true,
               "service" => "/rosapi/topics"
             } = resp

      topics = Enum.zip(resp["values"]["topics"], resp["values"]["types"])
      assert {"/#{robot}/odom", "nav_msgs/msg/Odometry"} in topics
      assert {"/#{robot}/scan", "sensor_msgs/msg/LaserScan"} in topics
      assert {"/map", "nav_msgs/msg/OccupancyGrid"} in topics

      {[resp], s} = send_msg(s, %{op: "call_service", id: 7, service: "/rosapi/get_ros_version"})
      assert resp["values"] == %{"version" => 2, "distro" => "humble"}
      assert resp["id"] == 7

      {[resp], _s} = send_msg(s, %{op: "call_service", id: "x", service: "/spawn", args: %{}})
      assert %{"result" => false, "values" => "Service /spawn does not exist", "id" => "x"} = resp
    end

    test "hostile and malformed messages get status errors and leave the session working" do
      robot = robot!()
      odom(robot, 1.0, 1.0)
      s = open()

      for {text, expected} <- [
            {"{not json", "invalid JSON"},
            {"", "invalid JSON"},
            {"[1,2,3]", "is a JSON object"},
            {"42", "is a JSON object"},
            {~s({"id":"n"}), "needs an op"},
            {~s({"op":"teleport","id":"n"}), "unknown op \\\"teleport\\\""},
            {~s({"op":17}), "unknown op 17"},
            {~s({"op":"fragment","id":"f","data":"x","num":0,"total":2}), "not supported"},
            {~s({"op":"advertise_service","service":"/x","type":"std_srvs/Empty"}),
             "not supported"},
            {~s({"op":"service_response","service":"/x","result":true}),
             "calls no client services"},
            {~s({"op":"status","level":"error","msg":"hi"}), "sent by the server"},
            {~s({"op":"call_service"}), "a service name is required"},
            {~s({"op":"call_service","service":{"a":1}}), "a service name is required"},
            {~s({"op":"call_service","service":"/rosapi/topics","args":"all"}),
             "arguments must be an object"},
            {~s({"op":"set_level","level":"debug"}), "set_level: level is one of"},
            {~s({"op":"subscribe","topic":"/) <> String.duplicate("a", 10_000) <> ~s("}),
             "too long"},
            {~s({"op":"unsubscribe","topic":null}), nil}
          ] do
        case send_msg(s, text) do
          {[frame], ^s} when expected != nil ->
            assert frame["op"] in ["status", "service_response"]

            assert (frame["msg"] || frame["values"]) =~ String.replace(expected, "\\\"", "\""),
                   text

          {[], ^s} when expected == nil ->
            :ok

          other ->
            flunk("#{inspect(text, limit: 5)} gave #{inspect(other, limit: 5)}")
        end
      end

      # still working
      {frames, _s} = send_msg(s, %{op: "subscribe", topic: "/#{robot}/odom"})
      assert [_] = published(frames, "/#{robot}/odom")
    end

    test "set_level none silences statuses; info shows them" do
      s = open()
      {[], s} = send_msg(s, %{op: "set_level", level: "none"})
      assert {[], s} = send_msg(s, %{op: "nope"})
      {[], s} = send_msg(s, %{op: "set_level", level: "info"})
      {[%{"level" => "info"}], _} = send_msg(s, %{op: "auth", mac: token()})
    end

    test "the socket's error frames are status errors" do
      assert :jiffy.decode(Session.error_frame("too many messages"), [:return_maps]) ==
               %{"op" => "status", "level" => "error", "msg" => "too many messages"}
    end
  end

  defp mine?(%{"transforms" => transforms}, name),
    do: Enum.any?(transforms, &String.starts_with?(&1["child_frame_id"], name <> "/"))

  # A map request; refused by the node's map budget (spent by another
  # test this second), asked again in the next second, up to 3 times.
  defp map_request(s, message, tries \\ 3) do
    {frames, s} = send_msg(s, message)

    refused =
      Enum.any?(frames, fn f -> is_binary(f["msg"]) and f["msg"] =~ "too many map requests" end)

    if refused and tries > 1 do
      Process.sleep(1_000 - rem(System.monotonic_time(:millisecond), 1_000))
      map_request(s, message, tries - 1)
    else
      {frames, s}
    end
  end
end
