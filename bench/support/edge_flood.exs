# The abuse of `mix tc.bench edge`, run as an OS process of its own (as a
# hostile client on the same host would be), so the robot's VM pays only
# for serving it:
#
#     elixir bench/support/edge_flood.exs MODE PORT N [HOLD_S]
#
#   connections  N TCP connections held HOLD_S seconds (nothing sent)
#   wrong_token  N requests with a wrong token: for the page's socket
#                (refused, 401) and its static files (served, 200)
#   map          N rosbridge subscribes to /map (each then unsubscribed)
#   restarts     N module restart requests on the page socket (token from
#                TC_EDGE_TOKEN, module names from TC_EDGE_MODULES)
#   malformed    N malformed page messages (with the token)
#
# It prints one line, `MODE sent=… ok=… refused=…`, and exits.

defmodule EdgeFlood do
  @host {127, 0, 0, 1}

  def main([mode, port, n | rest]) do
    port = String.to_integer(port)
    n = String.to_integer(n)
    {sent, ok, refused} = run(mode, port, n, rest)
    IO.puts("#{mode} sent=#{sent} ok=#{ok} refused=#{refused}")
  end

  defp run("connections", port, n, [hold]) do
    sockets =
      for _ <- 1..n do
        case :gen_tcp.connect(@host, port, [:binary, active: false], 2_000) do
          {:ok, s} -> s
          {:error, _} -> nil
        end
      end

    opened = Enum.count(sockets, & &1)
    Process.sleep(round(String.to_float(hold) * 1000))
    # how many the server had closed meanwhile (at its cap)
    closed =
      Enum.count(sockets, fn
        nil -> false
        s -> match?({:error, :closed}, :gen_tcp.recv(s, 0, 0))
      end)

    {n, opened, closed}
  end

  defp run("wrong_token", port, n, _) do
    statuses =
      1..n
      |> Task.async_stream(
        fn
          i when rem(i, 2) == 0 -> http_get(port, "/ws?token=wrong-#{i}", websocket: true)
          i -> http_get(port, "/?token=wrong-#{i}")
        end,
        max_concurrency: 16,
        timeout: 10_000,
        on_timeout: :kill_task
      )
      |> Enum.map(fn
        {:ok, status} -> status
        {:exit, _} -> :timeout
      end)

    # ok: answered as it should be (the socket refused, the files served)
    ok = Enum.count(statuses, &(&1 in [200, 401]))
    {n, ok, n - ok}
  end

  defp run("map", port, n, _) do
    messages =
      Stream.flat_map(1..n, fn i ->
        [
          ~s({"op":"subscribe","id":"m#{i}","topic":"/map"}),
          ~s({"op":"unsubscribe","id":"m#{i}","topic":"/map"})
        ]
      end)

    ws_flood(port, "/", messages)
  end

  defp run("restarts", port, n, _) do
    modules = String.split(System.get_env("TC_EDGE_MODULES", "planner"), ",")

    messages =
      Stream.map(1..n, fn i ->
        ~s({"op":"restart","id":#{i},"module":"#{Enum.at(modules, rem(i, length(modules)))}"})
      end)

    ws_flood(port, "/ws?token=#{System.get_env("TC_EDGE_TOKEN")}", messages)
  end

  defp run("malformed", port, n, _) do
    robot = System.get_env("TC_EDGE_ROBOT", "r1")

    bad = [
      "{not json",
      "[1, 2, 3]",
      ~s({"op": 42}),
      ~s({"op": "teleop", "robot": "#{robot}", "v": 1#{String.duplicate("0", 5000)}, "w": 0}),
      ~s({"op": "goal", "robot": "#{robot}", "x": -1e300, "y": 0}),
      ~s({"op": "goal", "robot": "#{robot}", "waypoint": "erlang"}),
      ~s({"op": "query", "template": [{"a": 1}]}),
      String.duplicate("[", 5000)
    ]

    messages = Stream.map(1..n, fn i -> Enum.at(bad, rem(i, length(bad))) end)
    ws_flood(port, "/ws?token=#{System.get_env("TC_EDGE_TOKEN")}", messages)
  end

  defp http_get(port, path, opts \\ []) do
    upgrade =
      if opts[:websocket],
        do:
          "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n" <>
            "Sec-WebSocket-Key: #{Base.encode64(:crypto.strong_rand_bytes(16))}\r\n",
        else: ""

    with {:ok, s} <- :gen_tcp.connect(@host, port, [:binary, active: false], 2_000),
         :ok <- :gen_tcp.send(s, "GET #{path} HTTP/1.1\r\nHost: 127.0.0.1\r\n#{upgrade}\r\n"),
         {:ok, "HTTP/1.1 " <> <<code::binary-size(3), _::binary>>} <- :gen_tcp.recv(s, 0, 5_000) do
      :gen_tcp.close(s)
      String.to_integer(code)
    else
      _ -> :error
    end
  end

  # sends every message, a connection at a time: a connection the server
  # closes (at its rate limit) is opened again; replies are read and dropped
  defp ws_flood(port, path, messages) do
    {sent, reconnects, _socket} =
      Enum.reduce(messages, {0, 0, nil}, fn text, {sent, reconnects, socket} ->
        socket = socket || ws_connect(port, path)

        case socket && ws_send(socket, text) do
          :ok ->
            case drain(socket) do
              :open -> {sent + 1, reconnects, socket}
              :closed -> {sent + 1, reconnects + 1, nil}
            end

          _ ->
            Process.sleep(50)
            {sent, reconnects + 1, nil}
        end
      end)

    {sent, sent, reconnects}
  end

  defp ws_connect(port, path) do
    key = Base.encode64(:crypto.strong_rand_bytes(16))

    with {:ok, s} <- :gen_tcp.connect(@host, port, [:binary, active: false], 2_000),
         :ok <-
           :gen_tcp.send(s, [
             "GET #{path} HTTP/1.1\r\nHost: 127.0.0.1:#{port}\r\nUpgrade: websocket\r\n",
             "Connection: Upgrade\r\nSec-WebSocket-Key: #{key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
           ]),
         {:ok, "HTTP/1.1 101" <> _} <- :gen_tcp.recv(s, 0, 5_000) do
      :inet.setopts(s, active: true)
      s
    else
      _ -> nil
    end
  end

  defp ws_send(socket, text) do
    mask = :crypto.strong_rand_bytes(4)
    len = byte_size(text)

    header =
      cond do
        len < 126 -> <<0x81, 0x80 + len>>
        len < 65_536 -> <<0x81, 0xFE, len::16>>
        true -> <<0x81, 0xFF, len::64>>
      end

    masks = :binary.copy(mask, div(len, 4) + 1) |> binary_part(0, len)
    :gen_tcp.send(socket, [header, mask, :crypto.exor(text, masks)])
  end

  defp drain(socket) do
    receive do
      {:tcp, ^socket, _data} -> drain(socket)
      {:tcp_closed, ^socket} -> :closed
      {:tcp_error, ^socket, _} -> :closed
    after
      0 -> :open
    end
  end
end

EdgeFlood.main(System.argv())
