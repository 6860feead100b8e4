defmodule ThinkingCap.Dashboard.RosbridgeSocketTest do
  # The rosbridge port over real WebSockets: hostile and malformed input
  # (bad JSON, unknown ops, huge frames, floods) gets errors and leaves the
  # server running; browsers' origins are checked, the token is taken from
  # the URL.
  use ExUnit.Case, async: false

  import ThinkingCap.Dashboard.Test.Rosbridge, only: [robot!: 0]

  alias ThinkingCap.{Blackboard, Dashboard}
  alias ThinkingCap.Dashboard.Test.WSClient

  @token "socket-test-token"
  @max_frame 65_536

  setup do
    {:ok, info} =
      Dashboard.start(
        port: 0,
        rosbridge_port: 0,
        token: @token,
        max_frame: @max_frame,
        origins: ["http://tools.example"]
      )

    on_exit(fn -> Dashboard.stop() end)
    %{info: info}
  end

  defp connect(info, query \\ "", headers \\ []),
    do: WSClient.connect("127.0.0.1", info.rosbridge_port, "/" <> query, headers)

  defp request(client, message) do
    id = "req#{System.unique_integer([:positive])}"
    :ok = WSClient.send_text(client, :jiffy.encode(Map.put(message, :id, id)))
    {:ok, reply, client} = WSClient.recv_json_until(client, &(&1["id"] == id))
    {reply, client}
  end

  # reads (and drops) what comes until the server closes the connection
  defp read_until_closed(client) do
    case WSClient.recv(client, 5_000) do
      {{:close, code}, _} -> {:closed, code}
      {{:error, reason}, _} -> {:closed, reason}
      {_message, client} -> read_until_closed(client)
    end
  end

  # the server still answers a new client
  defp assert_serving(info) do
    {:ok, client} = connect(info)
    {reply, client} = request(client, %{op: "call_service", service: "/rosapi/get_ros_version"})
    assert %{"op" => "service_response", "result" => true, "values" => %{"version" => 2}} = reply
    WSClient.close(client)
  end

  test "bad JSON, unknown ops and wrong types get status errors; the connection goes on", %{
    info: info
  } do
    {:ok, client} = connect(info)

    :ok = WSClient.send_text(client, "{\"op\":\"subscribe\",")
    {:ok, reply, client} = WSClient.recv_json_until(client, &(&1["op"] == "status"))
    assert %{"level" => "error", "msg" => "invalid JSON" <> _} = reply

    {reply, client} = request(client, %{op: "warp_drive"})
    assert %{"op" => "status", "level" => "error", "msg" => "unknown op \"warp_drive\""} = reply

    {reply, client} = request(client, %{op: "subscribe", topic: 12, throttle_rate: "x"})
    assert %{"op" => "status", "level" => "error"} = reply

    {reply, client} = request(client, %{op: "publish", topic: %{}, msg: "go"})
    assert %{"op" => "status", "level" => "error"} = reply

    :ok = WSClient.send_frame(client, 2, <<0, 1, 2>>)
    {:ok, reply, client} = WSClient.recv_json_until(client, &(&1["op"] == "status"))
    assert reply["msg"] =~ "binary"

    {reply, client} = request(client, %{op: "call_service", service: "/rosapi/topics"})
    assert %{"op" => "service_response", "result" => true} = reply
    WSClient.close(client)
  end

  test "a frame above the size limit closes that connection only", %{info: info} do
    {:ok, client} = connect(info)

    huge =
      ~s({"op":"publish","topic":"/x","msg":") <> String.duplicate("a", @max_frame * 2) <> ~s("})

    _ = WSClient.send_text(client, huge)

    assert {:closed, code} = read_until_closed(client)
    assert code in [1009, :closed, :econnreset]
    WSClient.close(client)
    assert_serving(info)
  end

  test "a flood is cut off and the server keeps serving", %{info: info} do
    {:ok, client} = connect(info)
    flood = fn n -> for _ <- 1..n, do: WSClient.send_text(client, ~s({"op":"flood"})) end

    # over the budget: the surplus is dropped, with a warning
    flood.(300)

    assert {:ok, %{"level" => "error"}, client} =
             WSClient.recv_json_until(client, &(&1["msg"] =~ "too many messages"))

    # a client that keeps on is closed
    flood.(3_000)

    assert {:closed, code} = read_until_closed(client)
    assert code in [1008, :closed, :econnreset]
    assert_serving(info)
  end

  test "browsers must come from an allowed origin; other clients need none", %{info: info} do
    assert {:error, {:http, "HTTP/1.1 403" <> _}} =
             connect(info, "", [{"origin", "http://evil.example"}])

    assert {:ok, client} = connect(info, "", [{"origin", "http://tools.example"}])
    WSClient.close(client)
    assert_serving(info)
  end

  test "the token in the URL allows /cmd_vel; a wrong one does not", %{info: info} do
    robot = robot!()
    publish = %{op: "publish", topic: "/#{robot}/cmd_vel", msg: %{linear: %{x: 0.1}}}

    {:ok, viewer} = connect(info, "?token=not-the-token")
    {reply, viewer} = request(viewer, publish)
    assert %{"level" => "error", "msg" => "publish: publishing " <> _} = reply
    assert Blackboard.rdp({:teleop, robot, :_}) == :none
    WSClient.close(viewer)

    {:ok, driver} = connect(info, "?token=#{@token}")
    :ok = WSClient.send_text(driver, :jiffy.encode(publish))
    # nothing comes back from a publish: ask something to know it was handled
    {_reply, driver} = request(driver, %{op: "call_service", service: "/rosapi/get_time"})

    assert {:ok, {:teleop, ^robot, %{command: {:velocity, 0.1, _}}}} =
             Blackboard.rdp({:teleop, robot, :_})

    # closing the connection hands the robot back
    WSClient.close(driver)

    released =
      Enum.find_value(1..100, fn _ ->
        Process.sleep(20)
        match?({:ok, {:teleop, _, %{command: :release}}}, Blackboard.rdp({:teleop, robot, :_}))
      end)

    assert released
  end
end
