defmodule ThinkingCap.Dashboard.Foxglove.Handshake do
  @moduledoc false
  # The Foxglove port's HTTP upgrade: reads the request (the socket in
  # `packet: :http_bin` mode), checks it and answers 101 with the
  # subprotocol chosen, or refuses it with a status and a line of text.
  #
  # Checks, in order: a WebSocket upgrade (GET, Upgrade, a key, version
  # 13); a browser's Origin (the dashboard's rule); the access token
  # (`?token=`), unless the dashboard's `public_view` is on; a subprotocol
  # the endpoint speaks (`foxglove.sdk.v1` or `foxglove.websocket.v1`, the
  # client's first choice among them).

  alias ThinkingCap.Dashboard.Core.Access

  @subprotocols ["foxglove.sdk.v1", "foxglove.websocket.v1"]
  @max_headers 64
  @guid "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"

  @type request :: %{path: String.t(), query: map(), headers: %{String.t() => String.t()}}

  @doc "The subprotocol names the endpoint accepts."
  @spec subprotocols() :: [String.t()]
  def subprotocols, do: @subprotocols

  @doc "Reads the request's line and headers, within `timeout` ms in all."
  @spec read(port(), timeout()) :: {:ok, request()} | {:error, term()}
  def read(socket, timeout) do
    deadline = System.monotonic_time(:millisecond) + timeout

    with {:ok, {:http_request, :GET, {:abs_path, target}, _version}} <-
           :gen_tcp.recv(socket, 0, timeout),
         {:ok, headers} <- headers(socket, deadline, %{}, 0) do
      {path, query} = split_target(target)
      {:ok, %{path: path, query: query, headers: headers}}
    else
      {:ok, {:http_request, _method, _target, _version}} -> {:error, :not_get}
      {:ok, other} -> {:error, {:unexpected, other}}
      {:error, reason} -> {:error, reason}
    end
  end

  defp headers(_socket, _deadline, _acc, n) when n > @max_headers, do: {:error, :too_many_headers}

  defp headers(socket, deadline, acc, n) do
    left = max(deadline - System.monotonic_time(:millisecond), 0)

    case :gen_tcp.recv(socket, 0, left) do
      {:ok, {:http_header, _, name, _, value}} ->
        key = name |> to_string() |> String.downcase()
        value = to_string(value)
        acc = Map.update(acc, key, value, &(&1 <> ", " <> value))
        headers(socket, deadline, acc, n + 1)

      {:ok, :http_eoh} ->
        {:ok, acc}

      {:ok, other} ->
        {:error, {:unexpected, other}}

      {:error, reason} ->
        {:error, reason}
    end
  end

  defp split_target(target) do
    case String.split(target, "?", parts: 2) do
      [path, query] -> {path, decode_query(query)}
      [path] -> {path, %{}}
    end
  end

  defp decode_query(query) do
    URI.decode_query(query)
  rescue
    _ -> %{}
  end

  @doc """
  Checks the request against the running dashboard's `config`: `{:ok,
  subprotocol, control?}` or `{:refuse, status, text}`.
  """
  @spec check(request(), map()) ::
          {:ok, String.t(), boolean()} | {:refuse, pos_integer(), String.t()}
  def check(request, config) do
    h = request.headers
    origin = h["origin"]
    control = Access.valid_token?(request.query["token"], config.token)

    cond do
      not upgrade?(h) ->
        {:refuse, 400, "a WebSocket upgrade (version 13) is expected here"}

      origin != nil and not Access.origin_allowed?(origin, config) ->
        {:refuse, 403, "origin #{origin} is not allowed"}

      not control and not config.public_view ->
        {:refuse, 401, "an access token is required (the URL printed at start has it)"}

      true ->
        case choose(h["sec-websocket-protocol"]) do
          nil ->
            {:refuse, 400,
             "subprotocol #{Enum.join(@subprotocols, " or ")} is required (Sec-WebSocket-Protocol)"}

          subprotocol ->
            {:ok, subprotocol, control}
        end
    end
  end

  defp upgrade?(h) do
    tokens = fn value ->
      value |> to_string() |> String.downcase() |> String.split(~r/\s*,\s*/)
    end

    "websocket" in tokens.(h["upgrade"]) and "upgrade" in tokens.(h["connection"]) and
      h["sec-websocket-version"] == "13" and is_binary(h["sec-websocket-key"])
  end

  defp choose(nil), do: nil

  defp choose(offered) do
    offered
    |> String.split(",")
    |> Enum.map(&String.trim/1)
    |> Enum.find(&(&1 in @subprotocols))
  end

  @doc "The 101 answer for `request`, naming `subprotocol`."
  @spec accept(request(), String.t()) :: iodata()
  def accept(request, subprotocol) do
    key = String.trim(request.headers["sec-websocket-key"])
    accept = Base.encode64(:crypto.hash(:sha, key <> @guid))

    [
      "HTTP/1.1 101 Switching Protocols\r\n",
      "Upgrade: websocket\r\n",
      "Connection: Upgrade\r\n",
      "Sec-WebSocket-Accept: ",
      accept,
      "\r\n",
      "Sec-WebSocket-Protocol: ",
      subprotocol,
      "\r\n\r\n"
    ]
  end

  @doc "A refusal: `status` with `text`, and the connection closed."
  @spec refusal(pos_integer(), String.t()) :: iodata()
  def refusal(status, text) do
    body = text <> "\n"

    [
      "HTTP/1.1 #{status} #{reason(status)}\r\n",
      "Content-Type: text/plain\r\n",
      "Content-Length: #{byte_size(body)}\r\n",
      "Connection: close\r\n\r\n",
      body
    ]
  end

  defp reason(400), do: "Bad Request"
  defp reason(401), do: "Unauthorized"
  defp reason(403), do: "Forbidden"
  defp reason(503), do: "Service Unavailable"
  defp reason(_), do: "Error"
end
