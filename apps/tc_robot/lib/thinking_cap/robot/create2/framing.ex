defmodule ThinkingCap.Robot.Create2.Framing do
  @moduledoc """
  Cuts Create 2 stream frames (`[19][n][id][data]...[checksum]`, see
  `ThinkingCap.Robot.Create2.Protocol`) out of the bytes read from the
  serial line: a `ThinkingCap.Robot.UART.Framing` implementation, given
  to the UART as `framing: {ThinkingCap.Robot.Create2.Framing, ids}` with
  the packet ids the driver streams.

  Frames it delivers:

    * a valid frame: the whole frame as a binary, header to checksum (its
      `n` is what `ids` need, its packets are `ids` in order, its checksum
      is right); `Protocol.parse_frame/2` decodes it;
    * `{:rejected, reason, bytes}` for anything else, so the reader counts
      it: `:bad_length` (a header whose `n` is not the expected one),
      `:checksum` (a frame of the right shape with a wrong checksum),
      `:bad_packets` (the ids are not the expected ones), `:truncated` (a
      frame cut short: another header starts inside it), `:garbage` (bytes
      outside any frame).

  After a rejected frame it resynchronises on the next plausible header:
  `19`, then the expected `n`, then the first expected id. A frame cut
  short whose bytes and the next frame's first ones happen to make a valid
  frame (the checksum is right by chance, 1 in 256) is caught by the
  plausible header inside it; a frame whose last byte is a header byte
  waits for the bytes after it. A header
  without enough bytes after it waits for more (`:in_frame`); if the line
  stays quiet, `frame_timeout/1` hands the partial frame back. It never
  raises on any input.
  """

  @behaviour ThinkingCap.Robot.UART.Framing

  alias ThinkingCap.Robot.Create2.Protocol

  @header 19

  @typedoc "The framing state: the expected packets, `n`, and the bytes of a frame begun."
  @type t :: %__MODULE__{ids: [Protocol.packet_id()], n: non_neg_integer(), buffer: binary()}
  defstruct ids: [], n: 0, buffer: <<>>

  @typedoc "A frame or a rejected piece of the input."
  @type frame :: binary() | {:rejected, atom(), binary()}

  @doc """
  The framing state for a stream of the packets `ids` (a list, or `ids:`
  in a keyword list); `{:error, {:bad_packets, ids}}` for an empty list,
  an unknown id, or more than a frame can carry.
  """
  @spec init([Protocol.packet_id()] | keyword()) :: {:ok, t()} | {:error, term()}
  @impl true
  def init([{:ids, ids} | _]), do: init(ids)

  def init([_ | _] = ids) do
    case Protocol.stream_length(ids) do
      n when is_integer(n) and n < 256 -> {:ok, %__MODULE__{ids: ids, n: n}}
      _ -> {:error, {:bad_packets, ids}}
    end
  end

  def init(other), do: {:error, {:bad_packets, other}}

  @doc "Commands to the robot are not framed: `iodata` goes out as it is."
  @spec add_framing(iodata(), t()) :: {:ok, iodata(), t()}
  @impl true
  def add_framing(iodata, state), do: {:ok, iodata, state}

  @doc """
  Adds bytes read from the line; returns the frames (and rejected
  pieces) they complete, and `:in_frame` when a frame has begun and waits
  for more bytes, `:ok` otherwise.
  """
  @spec remove_framing(binary(), t()) :: {:in_frame | :ok, [frame()], t()}
  @impl true
  def remove_framing(data, %__MODULE__{} = state) when is_binary(data) do
    {frames, buffer} = scan(state.buffer <> data, state, [])
    {if(buffer == <<>>, do: :ok, else: :in_frame), frames, %{state | buffer: buffer}}
  end

  @doc """
  The line went quiet in the middle of a frame: the partial frame,
  dropped from the state. A complete frame held back to see what came
  after it (see the moduledoc) is handed back as a partial of its own,
  which `ThinkingCap.Robot.Create2.Protocol.parse_frame/2` accepts.
  """
  @spec frame_timeout(t()) :: {:ok, [binary()], t()}
  @impl true
  def frame_timeout(%__MODULE__{buffer: <<>>} = state), do: {:ok, [], state}

  def frame_timeout(%__MODULE__{buffer: buffer} = state) do
    length = state.n + 3

    partials =
      with <<candidate::binary-size(length), rest::binary>> <- buffer,
           {:ok, _} <- Protocol.parse_frame(candidate, state.ids) do
        Enum.reject([candidate, rest], &(&1 == <<>>))
      else
        _ -> [buffer]
      end

    {:ok, partials, %{state | buffer: <<>>}}
  end

  @doc "Forgets a frame begun when the receiving direction is flushed."
  @spec flush(atom(), t()) :: t()
  @impl true
  def flush(direction, state) when direction in [:receive, :both], do: %{state | buffer: <<>>}
  def flush(_direction, state), do: state

  # hunting for a header
  defp scan(<<>>, _state, acc), do: {Enum.reverse(acc), <<>>}

  defp scan(bytes, state, acc) do
    case :binary.match(bytes, <<@header>>) do
      :nomatch ->
        {Enum.reverse([{:rejected, :garbage, bytes} | acc]), <<>>}

      {0, _} ->
        header(bytes, state, acc)

      {p, _} ->
        <<garbage::binary-size(p), rest::binary>> = bytes
        header(rest, state, [{:rejected, :garbage, garbage} | acc])
    end
  end

  # `bytes` starts with a header byte
  defp header(<<@header>> = bytes, _state, acc), do: {Enum.reverse(acc), bytes}

  defp header(<<@header, n, _::binary>> = bytes, %{n: expected} = state, acc)
       when n != expected do
    <<_, rest::binary>> = bytes
    scan(rest, state, [{:rejected, :bad_length, <<@header, n>>} | acc])
  end

  defp header(bytes, state, acc) do
    length = state.n + 3

    if byte_size(bytes) < length do
      {Enum.reverse(acc), bytes}
    else
      <<candidate::binary-size(length), rest::binary>> = bytes

      case Protocol.parse_frame(candidate, state.ids) do
        {:ok, _} ->
          valid(bytes, candidate, rest, state, acc)

        {:error, reason} ->
          case resync(bytes, state, 1, length) do
            :wait ->
              {Enum.reverse(acc), bytes}

            {:at, p} ->
              <<cut::binary-size(p), rest::binary>> = bytes
              header(rest, state, [{:rejected, :truncated, cut} | acc])

            :none ->
              scan(rest, state, [{:rejected, reason, candidate} | acc])
          end
      end
    end
  end

  # A valid frame, unless a plausible header (19, n, first id) is inside
  # it: then it was a frame cut short whose bytes and the next frame's
  # first ones happened to sum right (1 in 256), and decoding it would
  # give wrong values. A real frame holds such a header only if its last
  # encoder count and checksum spell it. Only frames ending in a header
  # byte wait for the bytes after them.
  defp valid(bytes, candidate, rest, state, acc) do
    case resync(bytes, state, 1, byte_size(candidate)) do
      :none ->
        scan(rest, state, [candidate | acc])

      :wait ->
        {Enum.reverse(acc), bytes}

      {:at, p} ->
        <<cut::binary-size(p), rest::binary>> = bytes
        header(rest, state, [{:rejected, :truncated, cut} | acc])
    end
  end

  # The first plausible header at positions p..length-1 of a refused
  # candidate frame: 19, n, the first id. `:wait` when a header byte
  # might begin one but the bytes telling are not there yet.
  defp resync(_bytes, _state, p, length) when p >= length, do: :none

  defp resync(bytes, state, p, length) do
    case plausible(bytes, p, state) do
      :yes -> {:at, p}
      :maybe -> :wait
      :no -> resync(bytes, state, p + 1, length)
    end
  end

  defp plausible(bytes, p, %{n: n, ids: [first | _]}) do
    case bytes do
      <<_::binary-size(p), @header, ^n, ^first, _::binary>> -> :yes
      <<_::binary-size(p), @header, ^n>> -> :maybe
      <<_::binary-size(p), @header>> -> :maybe
      _ -> :no
    end
  end
end
