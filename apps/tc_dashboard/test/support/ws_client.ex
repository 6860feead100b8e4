defmodule ThinkingCap.Dashboard.Test.WSClient do
  @moduledoc """
  A small WebSocket client for tests (RFC 6455 over `:gen_tcp`, no
  extensions): it can also send what a well-behaved client never would
  (oversized frames, unmasked frames, floods).
  """

  defstruct [:socket, buffer: <<>>]

  @type t :: %__MODULE__{socket: :gen_tcp.socket(), buffer: binary()}

  @doc """
  Opens `ws://host:port/path`. `headers` are extra request headers (e.g.
  `[{"origin", "http://evil.example"}]`). Returns `{:ok, client}` or
  `{:error, {:http, status_line}}` when the server refuses the upgrade.
  """
  @spec connect(String.t(), :inet.port_number(), String.t(), [{String.t(), String.t()}]) ::
          {:ok, t()} | {:error, term()}
  def connect(host, port, path, headers \\ []) do
    key = Base.encode64(:crypto.strong_rand_bytes(16))

    request = [
      "GET #{path} HTTP/1.1\r\n",
      "Host: #{host}:#{port}\r\n",
      "Upgrade: websocket\r\n",
      "Connection: Upgrade\r\n",
      "Sec-WebSocket-Key: #{key}\r\n",
      "Sec-WebSocket-Version: 13\r\n",
      Enum.map(headers, fn {k, v} -> "#{k}: #{v}\r\n" end),
      "\r\n"
    ]

    with {:ok, socket} <-
           :gen_tcp.connect(
             to_charlist(host),
             port,
             [:binary, active: false, packet: :raw],
             5_000
           ),
         :ok <- :gen_tcp.send(socket, request),
         {:ok, response, rest} <- read_head(socket, <<>>) do
      case response do
        "HTTP/1.1 101" <> _ ->
          {:ok, %__MODULE__{socket: socket, buffer: rest}}

        _ ->
          :gen_tcp.close(socket)
          {:error, {:http, response |> String.split("\r\n") |> hd()}}
      end
    end
  end

  @doc "Sends a text message (one masked, final frame)."
  @spec send_text(t(), iodata()) :: :ok | {:error, term()}
  def send_text(client, text), do: send_frame(client, 1, IO.iodata_to_binary(text))

  @doc "Sends one frame: `opcode` (1 text, 2 binary, 8 close, 9 ping), masked unless `mask: false`."
  @spec send_frame(t(), 0..15, binary(), keyword()) :: :ok | {:error, term()}
  def send_frame(client, opcode, payload, opts \\ []) do
    fin = if Keyword.get(opts, :fin, true), do: 1, else: 0
    len = byte_size(payload)

    len_bits =
      cond do
        len < 126 -> <<len::7>>
        len < 65_536 -> <<126::7, len::16>>
        true -> <<127::7, len::64>>
      end

    frame =
      if Keyword.get(opts, :mask, true) do
        key = :crypto.strong_rand_bytes(4)

        <<fin::1, 0::3, opcode::4, 1::1, len_bits::bitstring, key::binary,
          mask(payload, key)::binary>>
      else
        <<fin::1, 0::3, opcode::4, 0::1, len_bits::bitstring, payload::binary>>
      end

    :gen_tcp.send(client.socket, frame)
  end

  @doc """
  Receives the next message: `{:text, binary}`, `{:binary, binary}`,
  `{:close, code}`, `{:ping, data}`; `{:error, :closed | :timeout}`.
  """
  @spec recv(t(), timeout()) :: {term(), t()}
  def recv(client, timeout \\ 5_000) do
    case parse(client.buffer) do
      {:ok, message, rest} ->
        {message, %{client | buffer: rest}}

      :more ->
        case :gen_tcp.recv(client.socket, 0, timeout) do
          {:ok, data} -> recv(%{client | buffer: client.buffer <> data}, timeout)
          {:error, reason} -> {{:error, reason}, client}
        end
    end
  end

  @doc "Receives until a text message decodes to JSON for which `fun` is true; returns it."
  @spec recv_json_until(t(), (map() -> boolean()), timeout()) ::
          {:ok, map(), t()} | {:error, term(), t()}
  def recv_json_until(client, fun, timeout \\ 5_000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    do_recv_until(client, fun, deadline)
  end

  defp do_recv_until(client, fun, deadline) do
    left = max(deadline - System.monotonic_time(:millisecond), 0)

    case recv(client, left) do
      {{:text, text}, client} ->
        message = :jiffy.decode(text, [:return_maps, :use_nil])
        if fun.(message), do: {:ok, message, client}, else: do_recv_until(client, fun, deadline)

      {{:ping, _}, client} ->
        do_recv_until(client, fun, deadline)

      {other, client} ->
        {:error, other, client}
    end
  end

  @doc "Closes the connection."
  @spec close(t()) :: :ok
  def close(client), do: :gen_tcp.close(client.socket)

  defp read_head(socket, acc) do
    case :binary.split(acc, "\r\n\r\n") do
      [head, rest] ->
        {:ok, head, rest}

      [_] ->
        case :gen_tcp.recv(socket, 0, 5_000) do
          {:ok, data} -> read_head(socket, acc <> data)
          {:error, reason} -> {:error, reason}
        end
    end
  end

  defp parse(<<_fin::1, _::3, opcode::4, 0::1, 127::7, len::64, rest::binary>>)
       when byte_size(rest) >= len,
       do: message(opcode, rest, len)

  defp parse(<<_fin::1, _::3, opcode::4, 0::1, 126::7, len::16, rest::binary>>)
       when byte_size(rest) >= len,
       do: message(opcode, rest, len)

  defp parse(<<_fin::1, _::3, opcode::4, 0::1, len::7, rest::binary>>)
       when len < 126 and byte_size(rest) >= len,
       do: message(opcode, rest, len)

  defp parse(_), do: :more

  defp message(opcode, rest, len) do
    <<payload::binary-size(len), rest::binary>> = rest

    message =
      case opcode do
        1 -> {:text, payload}
        2 -> {:binary, payload}
        8 -> {:close, close_code(payload)}
        9 -> {:ping, payload}
        10 -> {:pong, payload}
        other -> {:opcode, other, payload}
      end

    {:ok, message, rest}
  end

  defp close_code(<<code::16, _::binary>>), do: code
  defp close_code(_), do: nil

  defp mask(payload, <<k::32>>) do
    whole = div(byte_size(payload), 4) * 4
    <<body::binary-size(whole), tail::binary>> = payload
    masked = for <<w::32 <- body>>, into: <<>>, do: <<Bitwise.bxor(w, k)::32>>
    <<kb::binary-size(byte_size(tail)), _::binary>> = <<k::32>>
    masked <> :crypto.exor(tail, kb)
  end
end
