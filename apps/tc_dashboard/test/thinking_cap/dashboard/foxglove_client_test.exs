defmodule ThinkingCap.Dashboard.FoxgloveClientTest do
  # The Foxglove port with Foxglove's own npm client (`@foxglove/ws-protocol`
  # over `ws`), in Node, and a simulated robot in the office: it connects
  # with either subprotocol name, lists the channels, and decodes a
  # LaserScan, a Grid and a pose — or is refused without the token.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Dashboard, Runtime}
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :tmp_dir
  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @script Path.expand("../../support/js/foxglove_client.mjs", __DIR__)
  @token "foxglove-test-token"

  setup %{tmp_dir: dir} = ctx do
    node =
      System.find_executable("node") || flunk("node is not installed (bin/setup installs it)")

    File.exists?(Path.expand("../../../assets/node_modules/@foxglove/ws-protocol", __DIR__)) ||
      flunk("@foxglove/ws-protocol is not installed in apps/tc_dashboard/assets (npm ci)")

    robot = :"fox#{System.unique_integer([:positive])}"
    adf = Path.join(dir, "foxglove.adf")

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
        rosbridge_port: nil,
        foxglove_port: 0,
        token: @token,
        public_view: ctx[:public_view] == true
      )

    on_exit(fn -> Dashboard.stop() end)
    {:ok, _} = Runtime.start(adf)

    on_exit(fn ->
      Runtime.stop(:"base_#{robot}")
      # the tuples written below go with the robot: other tests count maps
      Blackboard.takep(Tuples.pose(robot))
      Blackboard.takep(Tuples.map(robot))

      with {:ok, sim} <- ThinkingCap.Sim.Worlds.lookup("#{@examples}/office.wdf"),
           do: ThinkingCap.Sim.remove_robot(sim, robot)
    end)

    {:ok, _} = Blackboard.rd(Tuples.reading(:laser, robot), 5_000)

    # no localizer or mapper runs here: their tuples are written as they would
    Blackboard.out(
      Tuples.pose(robot, %{pose: {6.0, 1.5, 0.5}, covariance: nil, stamp: 12.25}),
      key: Tuples.key(Tuples.pose(robot, nil))
    )

    grid = OccupancyGrid.new(40, 30, resolution: 0.1, origin: {-1.0, 2.0}, fill: 0)
    Blackboard.out(Tuples.map(robot, grid), key: Tuples.key(Tuples.map(robot, nil)))

    %{robot: robot, info: info, node: node}
  end

  defp run(ctx, query, subprotocol) do
    url = "ws://127.0.0.1:#{ctx.info.foxglove_port}/#{query}"

    {out, status} =
      System.cmd(ctx.node, [@script, url, subprotocol, "#{ctx.robot}"], stderr_to_stdout: true)

    assert status == 0, "the Foxglove client failed (#{status}):\n#{out}"

    out
    |> String.split("\n", trim: true)
    |> Enum.flat_map(fn line ->
      case :jiffy.decode(line, [:return_maps, :use_nil]) do
        %{"event" => _} = event -> [event]
        _ -> []
      end
    end)
  rescue
    e in ErlangError -> flunk("the Foxglove client printed something else: #{inspect(e)}")
  end

  defp event(events, name),
    do:
      Enum.find(events, &(&1["event"] == name)) || flunk("no #{name} event in #{inspect(events)}")

  for subprotocol <- ["foxglove.websocket.v1", "foxglove.sdk.v1"] do
    test "Foxglove's client (#{subprotocol}) lists the channels and decodes a scan, a grid and a pose",
         ctx do
      name = Atom.to_string(ctx.robot)
      events = run(ctx, "?token=#{@token}", unquote(subprotocol))

      assert event(events, "open")["protocol"] == unquote(subprotocol)

      assert %{"name" => "ThinkingCap", "capabilities" => [], "supportedEncodings" => ["json"]} =
               event(events, "serverInfo")

      channels =
        for %{"event" => "advertise", "channels" => cs} <- events,
            c <- cs,
            into: %{},
            do: {c["topic"], c}

      for {topic, schema} <- [
            {"/#{name}/laser", "foxglove.LaserScan"},
            {"/#{name}/map", "foxglove.Grid"},
            {"/#{name}/pose", "foxglove.PoseInFrame"},
            {"/#{name}/tf", "foxglove.FrameTransform"}
          ] do
        assert %{"encoding" => "json", "schemaEncoding" => "jsonschema"} = channels[topic]
        assert channels[topic]["schemaName"] == schema
        assert channels[topic]["schemaTitle"] == schema
      end

      # the office robot's laser: 181 beams over 180°, in the robot's frame
      scan = event(events, "scan")
      assert scan["schemaName"] == "foxglove.LaserScan"
      assert scan["message"]["frame_id"] == "#{name}/base_link"
      assert length(scan["message"]["ranges"]) == 181
      assert_in_delta scan["message"]["start_angle"], -1.5708, 1.0e-3
      assert Enum.all?(scan["message"]["ranges"], &is_number/1)

      map = event(events, "map")["message"]
      assert map["frame_id"] == "map"
      assert map["column_count"] == 40
      assert map["cell_size"] == %{"x" => 0.1, "y" => 0.1}
      assert map["pose"]["position"] == %{"x" => -1.0, "y" => 2.0, "z" => 0.0}
      # base64 of 40 × 30 one-byte cells
      assert map["data"] == 1600

      pose = event(events, "pose")
      assert pose["timestamp"] == 12_250_000_000
      assert %{"sec" => 12, "nsec" => 250_000_000} = pose["message"]["timestamp"]
      assert pose["message"]["frame_id"] == "map"
      assert pose["message"]["pose"]["position"] == %{"x" => 6.0, "y" => 1.5, "z" => 0.0}
      # the black box's JSON writes floats to the millionth
      assert_in_delta pose["message"]["pose"]["orientation"]["z"], :math.sin(0.25), 1.0e-6

      assert event(events, "done")
      assert Enum.filter(events, &(&1["event"] in ["status", "error"])) == []
    end
  end

  test "without the token the connection is refused", ctx do
    assert event(run(ctx, "", "foxglove.websocket.v1"), "refused")["status"] == 401
    assert event(run(ctx, "?token=wrong-token-x", "foxglove.sdk.v1"), "refused")["status"] == 401
  end

  @tag public_view: true
  test "with public_view on, a client without the token may watch", ctx do
    events = run(ctx, "", "foxglove.sdk.v1")
    assert event(events, "open")["protocol"] == "foxglove.sdk.v1"
    assert event(events, "scan")["message"]["ranges"] != []
  end
end
