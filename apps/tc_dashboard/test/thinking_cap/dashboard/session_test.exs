defmodule ThinkingCap.Dashboard.SessionTest do
  # the page's WebSocket protocol, spoken by a plain WebSocket client
  use ThinkingCap.Dashboard.Test.Case, async: false

  alias ThinkingCap.Blackboard

  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  setup do
    robot = :"dr#{System.unique_integer([:positive])}"
    caps = %{limits: %{max_speed: 0.5, max_turn_rate: 1.0}, footprint: %{radius: 0.2}}
    Blackboard.out({:robot, robot, caps}, key: {:robot, robot})
    %{robot: robot, name: Atom.to_string(robot)}
  end

  @tag dashboard: [world: @office]
  test "the welcome tells the client its rights, the robots and the world", ctx do
    {welcome, client} = connect!(ctx.dashboard)
    assert welcome["control"] == true
    assert ctx.name in welcome["robots"]
    world = welcome["world"]
    assert length(world["walls"]) > 4
    assert Enum.any?(world["doors"], &is_binary(&1["name"]))
    assert %{"name" => "dock"} = Enum.find(world["waypoints"], &(&1["name"] == "dock"))
    WSClient.close(client)
  end

  test "without the token, or with a wrong one, the page is refused", ctx do
    assert {:error, {:http, "HTTP/1.1 401" <> _}} = connect(ctx.dashboard, "")
    assert {:error, {:http, "HTTP/1.1 401" <> _}} = connect(ctx.dashboard, "?token=nope")
    assert {:error, {:http, "HTTP/1.1 401" <> _}} = connect(ctx.dashboard, "?token=#{token()}x")
  end

  @tag dashboard: [public_view: true]
  test "with public viewing on, viewers without the token watch but never control", ctx do
    {welcome, client} = connect!(ctx.dashboard, "")
    assert welcome["control"] == false

    {reply, client} = request(client, %{op: "teleop", robot: ctx.name, v: 0.2, w: 0.0})
    assert %{"op" => "error", "message" => message} = reply
    assert message =~ "access token"
    assert :none == Blackboard.rdp({:teleop, ctx.robot, :_})

    for op <- ~w(teleop_release estop_release restart goal) do
      {reply, _} = request(client, %{op: op, robot: ctx.name, module: "x", x: 1, y: 1})
      assert reply["op"] == "error", op
    end

    # but anyone may stop a robot
    {reply, client} = request(client, %{op: "estop", robot: ctx.name})
    assert reply["op"] == "ok"
    assert {:ok, {:estop, _, %{engaged: true}}} = Blackboard.rdp({:estop, ctx.robot, :_})
    WSClient.close(client)
  end

  test "a browser from another origin is refused; the dashboard's own is let in", ctx do
    port = ctx.dashboard.port

    assert {:error, {:http, "HTTP/1.1 403" <> _}} =
             connect(ctx.dashboard, "?token=#{token()}", [{"Origin", "http://evil.example"}])

    assert {:error, {:http, "HTTP/1.1 403" <> _}} =
             connect(ctx.dashboard, "?token=#{token()}", [{"Origin", "http://127.0.0.1:1"}])

    for origin <- ["http://127.0.0.1:#{port}", "http://localhost:#{port}"] do
      assert {:ok, client} = connect(ctx.dashboard, "?token=#{token()}", [{"Origin", origin}])
      WSClient.close(client)
    end
  end

  @tag dashboard: [world: @office]
  test "controlling actions become blackboard writes, teleoperation clamped to the limits", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    {reply, client} =
      request(client, %{op: "teleop", robot: ctx.name, v: 2.0, w: -3.0, sent_at: 1.5e12})

    assert reply["op"] == "ok"

    assert {:ok,
            {:teleop, _, %{command: {:velocity, 0.5, -1.0}, sent_at: 1.5e12, by: "page " <> _}}} =
             Blackboard.rdp({:teleop, ctx.robot, :_})

    {%{"op" => "ok"}, client} = request(client, %{op: "teleop_release", robot: ctx.name})
    assert {:ok, {:teleop, _, %{command: :release}}} = Blackboard.rdp({:teleop, ctx.robot, :_})

    {%{"op" => "ok"}, client} = request(client, %{op: "estop", robot: ctx.name})
    assert {:ok, {:estop, _, %{engaged: true}}} = Blackboard.rdp({:estop, ctx.robot, :_})
    {%{"op" => "ok"}, client} = request(client, %{op: "estop_release", robot: ctx.name})
    assert {:ok, {:estop, _, %{engaged: false}}} = Blackboard.rdp({:estop, ctx.robot, :_})

    {%{"op" => "ok"}, client} = request(client, %{op: "goal", robot: ctx.name, x: 3, y: 4.5})

    assert {:ok, {:task, _, %{task: {:go_to, {3.0, 4.5}}}}} =
             Blackboard.rdp({:task, ctx.robot, :_})

    {%{"op" => "ok"}, client} = request(client, %{op: "goal", robot: ctx.name, waypoint: "dock"})
    assert {:ok, {:task, _, %{task: {:go_to, :dock}}}} = Blackboard.rdp({:task, ctx.robot, :_})

    # a place of the map a robot learned is a goal too
    Blackboard.out({:topology, ctx.robot, %{places: %{learned_room_7: %{}}}},
      key: {:topology, ctx.robot}
    )

    {%{"op" => "ok"}, client} =
      request(client, %{op: "goal", robot: ctx.name, waypoint: "learned_room_7"})

    assert {:ok, {:task, _, %{task: {:go_to, :learned_room_7}}}} =
             Blackboard.rdp({:task, ctx.robot, :_})

    WSClient.close(client)
  end

  test "bad messages get an error reply and the session goes on", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    bad = [
      "{not json",
      "[1, 2, 3]",
      "\"just a string\"",
      ~s({"no_op": true}),
      ~s({"op": "fly"}),
      ~s({"op": 42}),
      ~s({"op": "teleop", "robot": "#{ctx.name}", "v": "fast", "w": 0}),
      ~s({"op": "teleop", "robot": "no_such_robot_xyz", "v": 0.1, "w": 0}),
      ~s({"op": "teleop", "robot": 7, "v": 0.1, "w": 0}),
      ~s({"op": "goal", "robot": "#{ctx.name}", "x": "a"}),
      ~s({"op": "goal", "robot": "#{ctx.name}", "waypoint": "no_such_waypoint_q9z"}),
      ~s({"op": "query", "template": []}),
      ~s({"op": "query", "template": [{"a": 1}]}),
      ~s({"op": "tail", "template": ["pose", "_", "_"]}),
      ~s({"op": "restart", "module": "no_such_module_q9z"}),
      ~s({"op": "restart", "module": "no_such_module_q9z", "robot": {"a": 1}}),
      String.duplicate("[", 5000),
      # numbers too large for a robot, and an atom that exists but names no place
      ~s({"op": "teleop", "robot": "#{ctx.name}", "v": 1#{String.duplicate("0", 5000)}, "w": 0}),
      ~s({"op": "teleop", "robot": "#{ctx.name}", "v": 0.1, "w": -1e300}),
      ~s({"op": "goal", "robot": "#{ctx.name}", "x": -1e300, "y": 0}),
      ~s({"op": "goal", "robot": "#{ctx.name}", "waypoint": "erlang"})
    ]

    client =
      Enum.reduce(bad, client, fn text, client ->
        :ok = WSClient.send_text(client, text)
        {:ok, reply, client} = WSClient.recv_json_until(client, &(&1["op"] == "error"))
        assert is_binary(reply["message"]) and reply["message"] != "", text
        client
      end)

    # the error says which field is wrong
    for {text, expected} <- [
          {~s({"op": "teleop", "robot": "#{ctx.name}", "v": 1e12, "w": 0}), "v must be"},
          {~s({"op": "goal", "robot": "#{ctx.name}", "x": 1, "y": 1e9}), "y must be"},
          {~s({"op": "goal", "robot": "#{ctx.name}", "waypoint": "erlang"}), "no waypoint"}
        ] do
      :ok = WSClient.send_text(client, text)
      {:ok, reply, _} = WSClient.recv_json_until(client, &(&1["op"] == "error"))
      assert reply["message"] =~ expected
    end

    # binary frames are not understood either
    :ok = WSClient.send_frame(client, 2, <<1, 2, 3>>)

    {:ok, %{"message" => "binary" <> _}, client} =
      WSClient.recv_json_until(client, &(&1["op"] == "error"))

    # nothing was written, and the session still answers
    assert :none == Blackboard.rdp({:teleop, ctx.robot, :_})
    assert {%{"op" => "pong"}, client} = request(client, %{op: "ping"})
    WSClient.close(client)
  end

  test "a reply of a megabyte is one frame of valid JSON", ctx do
    tag = :"big#{System.unique_integer([:positive])}"
    text = String.duplicate("x", 2_100)
    for i <- 1..500, do: ThinkingCap.Blackboard.out({tag, :"r#{i}", %{text: text, i: i}})
    on_exit(fn -> for i <- 1..500, do: ThinkingCap.Blackboard.takep({tag, :"r#{i}", :_}) end)

    {_welcome, client} = connect!(ctx.dashboard)
    {reply, _client} = request(client, %{op: "query", template: [Atom.to_string(tag), "_", "_"]})
    assert reply["op"] == "result"
    assert length(reply["tuples"]) == 500
    assert IO.iodata_length(:jiffy.encode(reply)) > 1_000_000
  end

  @tag dashboard: [max_frame: 65_536]
  test "a frame above the size limit closes that socket; the server goes on", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    :ok =
      WSClient.send_text(
        client,
        ~s({"op":"ping","pad":") <> String.duplicate("x", 100_000) <> ~s("})
      )

    assert {:error, {:close, 1009}, _} = WSClient.recv_json_until(client, fn _ -> false end)

    {welcome, other} = connect!(ctx.dashboard)
    assert welcome["op"] == "welcome"
    assert {%{"op" => "pong"}, other} = request(other, %{op: "ping"})
    WSClient.close(other)
  end

  test "a flood is dropped with errors, then closed; other clients are served", ctx do
    {_welcome, flooder} = connect!(ctx.dashboard)
    {_welcome, other} = connect!(ctx.dashboard)

    frame = :jiffy.encode(%{op: "ping", id: 1})
    for _ <- 1..5_000, do: WSClient.send_text(flooder, frame)

    {pongs, errors, close} = drain(flooder, {0, 0, nil})
    # the burst is answered, the rest dropped with errors, then the socket closed
    assert pongs >= 100 and pongs < 5_000
    assert errors >= 1
    assert close == 1008

    assert {%{"op" => "pong"}, other} = request(other, %{op: "ping"})
    WSClient.close(other)
  end

  test "telemetry frames carry the streams that changed", ctx do
    {_welcome, client} = connect!(ctx.dashboard)
    key = "pose/#{ctx.name}"

    Blackboard.out({:pose, ctx.robot, %{pose: {1.0, 2.0, 0.5}, stamp: 3.0}},
      key: {:pose, ctx.robot}
    )

    {:ok, frame, client} =
      WSClient.recv_json_until(
        client,
        &(&1["op"] == "telemetry" and Map.has_key?(&1["items"], key))
      )

    assert frame["items"][key] == %{"pose" => [1.0, 2.0, 0.5], "stamp" => 3.0}
    assert is_integer(frame["t"])

    Blackboard.out({:pose, ctx.robot, %{pose: {4.0, 2.0, 0.5}, stamp: 4.0}},
      key: {:pose, ctx.robot}
    )

    {:ok, frame, client} =
      WSClient.recv_json_until(
        client,
        &(&1["op"] == "telemetry" and Map.has_key?(&1["items"], key))
      )

    # only what changed since the last frame
    assert frame["items"][key]["pose"] == [4.0, 2.0, 0.5]
    refute Map.has_key?(frame["items"], "robot/#{ctx.name}")
    WSClient.close(client)
  end

  test "a client that acknowledges frames has at most five unacknowledged", ctx do
    writer = spawn_link(fn -> write_poses(ctx.robot, 0) end)
    {_welcome, client} = connect!(ctx.dashboard)

    # acknowledge every frame up to the fourth, then stop
    {last_acked, client} = ack_frames(client, 4)
    {seqs, client} = frames_for(client, 600, [])
    # the five the window allows, then nothing
    assert Enum.sort(seqs) == Enum.to_list((last_acked + 1)..(last_acked + 5))

    # acknowledging opens the window again
    :ok = WSClient.send_text(client, :jiffy.encode(%{op: "ack", seq: Enum.max(seqs)}))
    {:ok, frame, client} = WSClient.recv_json_until(client, &(&1["op"] == "telemetry"))
    assert frame["seq"] == Enum.max(seqs) + 1

    # an acknowledgement of a frame never sent is refused
    {reply, client} = request(client, %{op: "ack", seq: 10_000})
    assert reply["op"] == "error" and reply["message"] =~ "10000"
    {reply, _client} = request(client, %{op: "ack"})
    assert reply["op"] == "error" and reply["message"] =~ "seq"
    Process.unlink(writer)
    Process.exit(writer, :kill)
  end

  defp write_poses(robot, n) do
    Blackboard.out({:pose, robot, %{pose: {n / 100, 0.0, 0.0}, stamp: n}}, key: {:pose, robot})
    Process.sleep(5)
    write_poses(robot, n + 1)
  end

  defp ack_frames(client, until) do
    {:ok, frame, client} = WSClient.recv_json_until(client, &(&1["op"] == "telemetry"))
    :ok = WSClient.send_text(client, :jiffy.encode(%{op: "ack", seq: frame["seq"]}))
    if frame["seq"] >= until, do: {frame["seq"], client}, else: ack_frames(client, until)
  end

  defp frames_for(client, ms, seqs) do
    case WSClient.recv_json_until(client, &(&1["op"] == "telemetry"), ms) do
      {:ok, frame, client} -> frames_for(client, ms, [frame["seq"] | seqs])
      {:error, _, client} -> {seqs, client}
    end
  end

  test "streams whose id is not a name are shown too, under a printed key", ctx do
    id = {:cart, make_ref()}
    Blackboard.out({:pose, id, %{pose: {0.0, 0.0, 0.0}}}, key: {:pose, id})
    # already there when the dashboard starts, and written while it runs
    ThinkingCap.Dashboard.stop()
    {:ok, info} = ThinkingCap.Dashboard.start(port: 0, rosbridge_port: nil, token: token())
    {_welcome, client} = connect!(info)
    Blackboard.out({:pose, id, %{pose: {1.0, 0.0, 0.0}}}, key: {:pose, id})
    key = "pose/#{inspect(id)}"

    # the value already there may come first, in a frame of its own
    {:ok, frame, client} =
      WSClient.recv_json_until(
        client,
        &(&1["op"] == "telemetry" and Map.has_key?(&1["items"], key) and
            &1["items"][key]["pose"] != [0.0, 0.0, 0.0])
      )

    assert frame["items"][key]["pose"] == [1.0, 0.0, 0.0]
    _ = ctx
    WSClient.close(client)
  end

  test "the blackboard inspector: query by template, live tail", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    {reply, client} = request(client, %{op: "query", template: ["robot", ctx.name, "_"]})
    assert [["robot", name, %{"limits" => %{"max_speed" => 0.5}}]] = reply["tuples"]
    assert name == ctx.name

    {%{"op" => "ok"}, client} = request(client, %{op: "tail", template: ["note", ctx.name, "_"]})
    Blackboard.out({:note, ctx.robot, %{n: 1}})
    Blackboard.out({:note, ctx.robot, %{n: 2}})

    {:ok, t1, client} = WSClient.recv_json_until(client, &(&1["op"] == "tuple"))
    {:ok, t2, client} = WSClient.recv_json_until(client, &(&1["op"] == "tuple"))

    assert [t1["tuple"], t2["tuple"]] == [
             ["note", ctx.name, %{"n" => 1}],
             ["note", ctx.name, %{"n" => 2}]
           ]

    WSClient.close(client)
  end

  @tag dashboard: [send_timeout: 300]
  test "a browser that stops reading is dropped, and never holds up the others", ctx do
    {_welcome, stalled} = connect!(ctx.dashboard)
    {_welcome, reader} = connect!(ctx.dashboard)
    key = "laser/#{ctx.name}"

    # big frames, 25 a second, for 2 s: far more than the stalled socket's buffers hold
    ranges = for i <- 1..20_000, do: i / 3

    pump =
      Task.async(fn ->
        for n <- 1..60 do
          Blackboard.out({:laser, ctx.robot, %{ranges: ranges, stamp: n * 1.0}},
            key: {:laser, ctx.robot}
          )

          Process.sleep(33)
        end
      end)

    # read until the last frame came (or 15 s: a loaded machine pumps slower)
    stamps = read_stamps(reader, key, System.monotonic_time(:millisecond) + 15_000, [])
    Task.await(pump, 10_000)
    # the reader kept getting fresh frames while the other stalled
    assert length(stamps) >= 10
    assert Enum.max(stamps) >= 50.0

    # the stalled one was dropped: after what its buffers held, the connection is closed
    assert drained_to_close?(stalled)
  end

  test "stopping the dashboard closes its sockets", ctx do
    {_welcome, client} = connect!(ctx.dashboard)
    assert [_] = ThinkingCap.Dashboard.Core.Socket.open_sockets()
    ThinkingCap.Dashboard.stop()
    assert drained_to_close?(client)
    assert {:error, _} = connect(ctx.dashboard)
  end

  defp read_stamps(client, key, deadline, acc) do
    if System.monotonic_time(:millisecond) > deadline do
      WSClient.close(client)
      acc
    else
      case WSClient.recv_json_until(client, &(&1["op"] == "telemetry"), 1_000) do
        {:ok, %{"items" => %{^key => %{"stamp" => s}}}, client} when s >= 60.0 ->
          WSClient.close(client)
          [s | acc]

        {:ok, %{"items" => %{^key => %{"stamp" => s}}}, client} ->
          read_stamps(client, key, deadline, [s | acc])

        {:ok, _, client} ->
          read_stamps(client, key, deadline, acc)

        {:error, _, _} ->
          acc
      end
    end
  end

  defp drained_to_close?(client) do
    case WSClient.recv(client, 5_000) do
      {{:error, :closed}, _} -> true
      {{:close, _}, _} -> true
      {{:error, :timeout}, _} -> false
      {_message, client} -> drained_to_close?(client)
    end
  end

  defp drain(client, {pongs, errors, _close} = acc) do
    case WSClient.recv(client, 5_000) do
      {{:text, text}, client} ->
        case :jiffy.decode(text, [:return_maps]) do
          %{"op" => "pong"} -> drain(client, {pongs + 1, errors, nil})
          %{"op" => "error"} -> drain(client, {pongs, errors + 1, nil})
          _ -> drain(client, acc)
        end

      {{:close, code}, _} ->
        {pongs, errors, code}

      {_other, _} ->
        acc
    end
  end
end
