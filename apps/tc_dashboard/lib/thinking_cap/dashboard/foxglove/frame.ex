defmodule ThinkingCap.Dashboard.Foxglove.Frame do
  @moduledoc false
  # WebSocket framing (RFC 6455) for the Foxglove port, which runs its own
  # small server: yaws 2.1 never answers a client's Sec-WebSocket-Protocol,
  # and Foxglove's clients (browsers, npm `ws`) fail a handshake that does
  # not name the subprotocol they asked for.
  #
  # Client frames must be masked; server frames are not. A frame whose
  # payload is over the limit is refused from its header, before it is read.

  @type opcode :: :continuation | :text | :binary | :close | :ping | :pong
  @type parsed ::
          {:frame, fin :: boolean(), opcode(), binary(), rest :: binary()}
          | :more
          | {:error, code :: pos_integer(), reason :: String.t()}

  @opcodes %{0 => :continuation, 1 => :text, 2 => :binary, 8 => :close, 9 => :ping, 10 => :pong}
  @codes Map.new(@opcodes, fn {code, name} -> {name, code} end)

  @doc "The first frame in `buffer`, or :more when it is not all there yet."
  @spec parse(binary(), pos_integer()) :: parsed()
  def parse(<<_fin::1, rsv::3, _op::4, _rest::binary>>, _max) when rsv != 0,
    do: {:error, 1002, "reserved bits set"}

  def parse(<<_fin::1, 0::3, _op::4, 0::1, _rest::binary>>, _max),
    do: {:error, 1002, "client frames must be masked"}

  def parse(<<fin::1, 0::3, op::4, 1::1, len7::7, rest::binary>>, max) do
    with {:ok, len, rest} <- length(len7, rest),
         :ok <- check(op, fin, len, max),
         <<mask::binary-4, payload::binary-size(len), rest::binary>> <- rest do
      {:frame, fin == 1, @opcodes[op], unmask(payload, mask), rest}
    else
      {:error, _code, _reason} = error -> error
      _short -> :more
    end
  end

  def parse(_buffer, _max), do: :more

  defp length(126, <<len::16, rest::binary>>), do: {:ok, len, rest}
  defp length(127, <<len::64, rest::binary>>), do: {:ok, len, rest}
  defp length(len, rest) when len < 126, do: {:ok, len, rest}
  defp length(_len, _rest), do: :more

  defp check(op, _fin, _len, _max) when not is_map_key(@opcodes, op),
    do: {:error, 1002, "unknown opcode #{op}"}

  defp check(op, fin, len, _max) when op >= 8 and (fin == 0 or len > 125),
    do: {:error, 1002, "control frames must be whole and short"}

  defp check(_op, _fin, len, max) when len > max,
    do: {:error, 1009, "frame of #{len} bytes is over the limit of #{max}"}

  defp check(_op, _fin, _len, _max), do: :ok

  defp unmask(<<>>, _mask), do: <<>>

  defp unmask(payload, mask) do
    n = byte_size(payload)
    :crypto.exor(payload, binary_part(:binary.copy(mask, div(n, 4) + 1), 0, n))
  end

  @doc "A server frame (unmasked, whole)."
  @spec encode(opcode(), iodata()) :: iodata()
  def encode(opcode, payload) do
    len = IO.iodata_length(payload)
    op = @codes[opcode]

    header =
      cond do
        len < 126 -> <<1::1, 0::3, op::4, 0::1, len::7>>
        len < 65_536 -> <<1::1, 0::3, op::4, 0::1, 126::7, len::16>>
        true -> <<1::1, 0::3, op::4, 0::1, 127::7, len::64>>
      end

    [header, payload]
  end

  @doc "A close frame with `code` and a short reason."
  @spec close(pos_integer(), String.t()) :: iodata()
  def close(code, reason),
    do: encode(:close, <<code::16, binary_part(reason, 0, min(byte_size(reason), 120))::binary>>)

  @doc "A masked client frame (for tests)."
  @spec client(opcode(), binary(), boolean()) :: binary()
  def client(opcode, payload, fin \\ true) do
    mask = :crypto.strong_rand_bytes(4)
    len = byte_size(payload)
    op = @codes[opcode]
    f = if fin, do: 1, else: 0

    len_bits =
      cond do
        len < 126 -> <<len::7>>
        len < 65_536 -> <<126::7, len::16>>
        true -> <<127::7, len::64>>
      end

    <<f::1, 0::3, op::4, 1::1, len_bits::bitstring, mask::binary, unmask(payload, mask)::binary>>
  end
end
