defmodule ThinkingCap.Dashboard.EdgeTest do
  # The network edge under abuse: the E-stop port that nothing else can
  # block, the connection cap per listener, and the web server brought
  # back when something kills it.
  use ThinkingCap.Dashboard.Test.Case, async: false

  alias ThinkingCap.Blackboard

  setup do
    robot = :"ep#{System.unique_integer([:positive])}"
    Blackboard.out({:robot, robot, %{}}, key: {:robot, robot})
    on_exit(fn -> Blackboard.takep({:robot, robot, :_}) end)
    %{robot: robot}
  end

  defp http(port, text) do
    {:ok, socket} = :gen_tcp.connect({127, 0, 0, 1}, port, [:binary, active: false], 1_000)
    :ok = :gen_tcp.send(socket, text)
    reply = read_all(socket, "")
    :gen_tcp.close(socket)
    reply
  end

  defp read_all(socket, acc) do
    case :gen_tcp.recv(socket, 0, 3_000) do
      {:ok, data} -> read_all(socket, acc <> data)
      {:error, _closed} -> acc
    end
  end

  defp estop(robot) do
    case Blackboard.rdp({:estop, robot, :_}) do
      {:ok, {:estop, _, %{engaged: engaged, by: by}}} -> {engaged, by}
      :none -> :none
    end
  end

  @tag dashboard: [estop_port: 0]
  test "the E-stop port engages E-stops, and does nothing else", ctx do
    port = ctx.dashboard.estop_port
    assert is_integer(port)

    assert "HTTP/1.1 200 OK" <> rest = http(port, "POST /estop/#{ctx.robot} HTTP/1.1\r\n\r\n")
    assert rest =~ "E-stop engaged: #{ctx.robot}"
    assert estop(ctx.robot) == {true, :estop_port}

    Blackboard.out({:estop, ctx.robot, %{engaged: false, by: :test}}, key: {:estop, ctx.robot})
    assert "HTTP/1.1 200" <> _ = http(port, "POST /estop HTTP/1.0\r\nHost: x\r\n\r\n")
    assert estop(ctx.robot) == {true, :estop_port}

    assert "HTTP/1.1 404" <> body = http(port, "POST /estop/no_such_robot HTTP/1.1\r\n\r\n")
    assert body =~ "no robot"
    assert "HTTP/1.1 405" <> _ = http(port, "GET /estop HTTP/1.1\r\n\r\n")
    assert "HTTP/1.1 404" <> _ = http(port, "GET / HTTP/1.1\r\n\r\n")
    assert "HTTP/1.1 400" <> _ = http(port, "\x16\x03\x01 not http at all\r\n\r\n")
  end

  @tag dashboard: [estop_port: 0]
  test "the E-stop port refuses beyond its cap at once, and serves again after", ctx do
    port = ctx.dashboard.estop_port

    idle =
      for _ <- 1..16 do
        {:ok, s} = :gen_tcp.connect({127, 0, 0, 1}, port, [:binary, active: false], 1_000)
        s
      end

    # the 17th is answered at once: busy
    Process.sleep(100)
    assert "HTTP/1.1 503" <> body = http(port, "POST /estop/#{ctx.robot} HTTP/1.1\r\n\r\n")
    assert body =~ "too many connections"
    assert estop(ctx.robot) == :none

    # the idle ones are dropped after their second to speak
    for s <- idle, do: assert({:error, :closed} = :gen_tcp.recv(s, 0, 3_000))
    assert "HTTP/1.1 200" <> _ = http(port, "POST /estop/#{ctx.robot} HTTP/1.1\r\n\r\n")
    assert estop(ctx.robot) == {true, :estop_port}
  end

  @tag dashboard: [max_connections: 4]
  test "beyond the connection cap a listener closes new connections at once", ctx do
    held =
      for _ <- 1..4 do
        {:ok, s} =
          :gen_tcp.connect({127, 0, 0, 1}, ctx.dashboard.port, [:binary, active: false], 1_000)

        s
      end

    Process.sleep(200)

    {:ok, extra} =
      :gen_tcp.connect({127, 0, 0, 1}, ctx.dashboard.port, [:binary, active: false], 1_000)

    assert {:error, :closed} = :gen_tcp.recv(extra, 0, 2_000)

    # a flood beyond the cap is closed connection by connection, and the
    # log says so once, not once per connection
    log =
      ExUnit.CaptureLog.capture_log(fn ->
        for _ <- 1..30 do
          {:ok, s} =
            :gen_tcp.connect({127, 0, 0, 1}, ctx.dashboard.port, [:binary, active: false], 1_000)

          {:error, :closed} = :gen_tcp.recv(s, 0, 2_000)
        end
      end)

    assert length(String.split(log, "Max connections reached")) <= 2

    # once they go, the page is served again
    Enum.each(held, &:gen_tcp.close/1)
    Process.sleep(200)
    assert {_welcome, client} = connect!(ctx.dashboard)
    WSClient.close(client)
  end

  @tag dashboard: [estop_port: 0]
  test "a web server killed again and again is brought back on its ports", ctx do
    # again and again: the web server (Core.WebServer) ends each time
    for _ <- 1..8 do
      if pid = Process.whereis(:yaws_server), do: Process.exit(pid, :kill)
      Process.sleep(20)
    end

    # back within a few seconds, on the same port, serving the page
    assert Enum.find_value(1..50, fn _ ->
             Process.sleep(100)
             match?({:ok, _}, connect(ctx.dashboard))
           end)

    assert {_welcome, client} = connect!(ctx.dashboard)
    WSClient.close(client)
    assert "HTTP/1.1 200" <> _ = http(ctx.dashboard.estop_port, "POST /estop HTTP/1.0\r\n\r\n")
  end
end
