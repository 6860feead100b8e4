defmodule ThinkingCap.Robot.Create2.Protocol do
  @moduledoc """
  The iRobot Create 2 Open Interface (OI), as pure functions: command
  encoders, sensor packet sizes, decoders and encoders, and stream frames.
  Nothing here does I/O; `ThinkingCap.Robot.Create2` (the driver) and
  `ThinkingCap.Testing.Create2Emulator` (the robot's side, for tests) both
  speak through it.

  The line is 115200 baud, 8N1, no flow control. Multi-byte values are
  big-endian.

  ## Commands

  | function | bytes |
  |---|---|
  | `start/0` | `[128]` |
  | `reset/0` | `[7]` |
  | `stop/0` | `[173]` |
  | `safe/0` | `[131]` |
  | `full/0` | `[132]` |
  | `power/0` | `[133]` |
  | `drive/2` | `[137, vel_hi, vel_lo, rad_hi, rad_lo]` |
  | `drive_direct/2` | `[145, right_hi, right_lo, left_hi, left_lo]` |
  | `sensors/1` | `[142, id]` |
  | `query_list/1` | `[149, n, id...]` |
  | `stream/1` | `[148, n, id...]` |
  | `pause_stream/0`, `resume_stream/0` | `[150, 0]`, `[150, 1]` |

  ## Stream frames

  Every 15 ms a streaming robot sends
  `[19][n][id1][data1...][id2][data2...]...[checksum]`: `n` counts the
  bytes between itself and the checksum, and the low byte of the sum of
  every byte of the frame, checksum included, is 0. `stream_frame/1`
  builds one, `parse_frame/2` checks and decodes one;
  `ThinkingCap.Robot.Create2.Framing` cuts them out of the byte stream.

  ## Packets

  Single packets 7 to 58 (the groups 0-6 and 100-107 are not supported).
  `decode/2` gives integers except for:

    * 7 (bumps and wheel drops): `%{bump_right:, bump_left:,
      wheel_drop_right:, wheel_drop_left:}` booleans;
    * 35 (OI mode): `:off`, `:passive`, `:safe`, `:full`.

  A reserved bit set in packet 7, or a mode above 3, is `:error`: a
  frame holding one is refused (`:bad_packets`), a cheap check on top of
  the 8-bit checksum.
  """

  import Bitwise

  @typedoc "An OI sensor packet id."
  @type packet_id :: 7..58

  @typedoc "An OI mode."
  @type mode :: :off | :passive | :safe | :full

  @header 19
  @max_velocity 500

  # id => {bytes, signed?}
  @packets %{
    7 => {1, false},
    8 => {1, false},
    9 => {1, false},
    10 => {1, false},
    11 => {1, false},
    12 => {1, false},
    13 => {1, false},
    14 => {1, false},
    15 => {1, false},
    16 => {1, false},
    17 => {1, false},
    18 => {1, false},
    19 => {2, true},
    20 => {2, true},
    21 => {1, false},
    22 => {2, false},
    23 => {2, true},
    24 => {1, true},
    25 => {2, false},
    26 => {2, false},
    27 => {2, false},
    28 => {2, false},
    29 => {2, false},
    30 => {2, false},
    31 => {2, false},
    32 => {1, false},
    33 => {2, false},
    34 => {1, false},
    35 => {1, false},
    36 => {1, false},
    37 => {1, false},
    38 => {1, false},
    39 => {2, true},
    40 => {2, true},
    41 => {2, true},
    42 => {2, true},
    43 => {2, false},
    44 => {2, false},
    45 => {1, false},
    46 => {2, false},
    47 => {2, false},
    48 => {2, false},
    49 => {2, false},
    50 => {2, false},
    51 => {2, false},
    52 => {1, false},
    53 => {1, false},
    54 => {2, true},
    55 => {2, true},
    56 => {2, true},
    57 => {2, true},
    58 => {1, false}
  }

  @modes %{0 => :off, 1 => :passive, 2 => :safe, 3 => :full}
  @mode_numbers Map.new(@modes, fn {n, m} -> {m, n} end)

  ## Commands

  @doc "Start (128): starts the OI; the robot goes to Passive mode."
  @spec start() :: binary()
  def start, do: <<128>>

  @doc "Reset (7): the robot resets as if its battery had been changed; OI Off."
  @spec reset() :: binary()
  def reset, do: <<7>>

  @doc "Stop (173): stops the OI (streams stop, commands are ignored); OI Off."
  @spec stop() :: binary()
  def stop, do: <<173>>

  @doc "Safe (131): Safe mode (a cliff or wheel drop stops the motors and reverts to Passive)."
  @spec safe() :: binary()
  def safe, do: <<131>>

  @doc "Full (132): Full mode, no safety features."
  @spec full() :: binary()
  def full, do: <<132>>

  @doc "Power (133): the robot powers down (Passive)."
  @spec power() :: binary()
  def power, do: <<133>>

  @doc "The command entering `mode` (`:safe` or `:full`)."
  @spec mode(:safe | :full) :: binary()
  def mode(:safe), do: safe()
  def mode(:full), do: full()

  @doc """
  Drive (137): velocity (mm/s, clamped to ±500) and turn radius (mm,
  ±2000); `radius` may also be `:straight` (32768), `:spin_ccw` (1) or
  `:spin_cw` (-1).
  """
  @spec drive(number(), number() | :straight | :spin_ccw | :spin_cw) :: binary()
  def drive(velocity, :straight), do: <<137, int16(velocity, @max_velocity)::16, 0x80, 0x00>>
  def drive(velocity, :spin_ccw), do: drive(velocity, 1)
  def drive(velocity, :spin_cw), do: drive(velocity, -1)

  def drive(velocity, radius),
    do: <<137, int16(velocity, @max_velocity)::16, int16(radius, 2000)::16>>

  @doc """
  Drive Direct (145): each wheel's speed in mm/s (positive forward),
  rounded and clamped to ±500. Note the wire order: right wheel first.
  """
  @spec drive_direct(number(), number()) :: binary()
  def drive_direct(left, right),
    do: <<145, int16(right, @max_velocity)::16, int16(left, @max_velocity)::16>>

  @doc "Sensors (142): asks for one packet."
  @spec sensors(packet_id()) :: binary()
  def sensors(id), do: <<142, id>>

  @doc "Query List (149): asks for several packets, answered in order."
  @spec query_list([packet_id()]) :: binary()
  def query_list(ids), do: IO.iodata_to_binary([149, length(ids) | ids])

  @doc "Stream (148): a frame of these packets every 15 ms."
  @spec stream([packet_id()]) :: binary()
  def stream(ids), do: IO.iodata_to_binary([148, length(ids) | ids])

  @doc "Pause/Resume Stream (150): pauses the stream."
  @spec pause_stream() :: binary()
  def pause_stream, do: <<150, 0>>

  @doc "Pause/Resume Stream (150): resumes the stream with the packets last asked for."
  @spec resume_stream() :: binary()
  def resume_stream, do: <<150, 1>>

  # a signed 16-bit value, rounded and clamped to ±limit
  defp int16(x, limit) do
    x |> round() |> max(-limit) |> min(limit) |> band(0xFFFF)
  end

  ## Packets

  @doc "The packet ids this module knows (7 to 58)."
  @spec packet_ids() :: [packet_id()]
  def packet_ids, do: @packets |> Map.keys() |> Enum.sort()

  @doc "The data size of packet `id` in bytes, or `nil` for an unknown id."
  @spec packet_size(integer()) :: 1 | 2 | nil
  def packet_size(id) do
    case @packets do
      %{^id => {size, _}} -> size
      _ -> nil
    end
  end

  @doc """
  The `n` byte of a stream frame of these packets: one byte per id plus
  each packet's data. `nil` if an id is unknown.
  """
  @spec stream_length([integer()]) :: non_neg_integer() | nil
  def stream_length(ids) do
    Enum.reduce_while(ids, 0, fn id, acc ->
      case packet_size(id) do
        nil -> {:halt, nil}
        size -> {:cont, acc + 1 + size}
      end
    end)
  end

  @doc "Decodes packet `id`'s data bytes; `:error` for a wrong size or an unknown id."
  @spec decode(integer(), binary()) :: term() | :error
  def decode(7, <<0::4, drop_left::1, drop_right::1, bump_left::1, bump_right::1>>) do
    %{
      bump_right: bump_right == 1,
      bump_left: bump_left == 1,
      wheel_drop_right: drop_right == 1,
      wheel_drop_left: drop_left == 1
    }
  end

  def decode(7, <<_>>), do: :error
  def decode(35, <<n>>), do: Map.get(@modes, n, :error)

  def decode(id, data) when is_binary(data) do
    case {@packets[id], data} do
      {{1, false}, <<v>>} -> v
      {{1, true}, <<v::signed>>} -> v
      {{2, false}, <<v::16>>} -> v
      {{2, true}, <<v::16-signed>>} -> v
      _ -> :error
    end
  end

  def decode(_id, _data), do: :error

  @doc """
  Encodes packet `id`'s value (the inverse of `decode/2`): integers are
  truncated to the packet's size (an encoder count of 70000 wraps to 4464),
  packet 7 takes the map `decode/2` gives, packet 35 a mode atom.
  """
  @spec encode(packet_id(), term()) :: binary()
  def encode(7, %{} = b) do
    <<0::4, bit(b[:wheel_drop_left])::1, bit(b[:wheel_drop_right])::1, bit(b[:bump_left])::1,
      bit(b[:bump_right])::1>>
  end

  def encode(35, mode) when is_atom(mode), do: <<Map.fetch!(@mode_numbers, mode)>>

  def encode(id, value) when is_integer(value) do
    case Map.fetch!(@packets, id) do
      {1, _} -> <<band(value, 0xFF)>>
      {2, _} -> <<band(value, 0xFFFF)::16>>
    end
  end

  defp bit(true), do: 1
  defp bit(_), do: 0

  @doc "The OI mode number of a mode atom (`:off` 0 ... `:full` 3)."
  @spec mode_number(mode()) :: 0..3
  def mode_number(mode), do: Map.fetch!(@mode_numbers, mode)

  ## Stream frames

  @doc "A stream frame of `{id, value}` packets, checksum included."
  @spec stream_frame([{packet_id(), term()}]) :: binary()
  def stream_frame(packets) do
    body = IO.iodata_to_binary(for {id, value} <- packets, do: [id, encode(id, value)])
    head = <<@header, byte_size(body)>> <> body
    head <> <<checksum(head)>>
  end

  @doc "The checksum byte making the low byte of the sum of `bytes` and itself 0."
  @spec checksum(binary()) :: byte()
  def checksum(bytes), do: band(0x100 - band(sum(bytes), 0xFF), 0xFF)

  @doc "Whether the low byte of the sum of every byte of `frame` is 0."
  @spec checksum_ok?(binary()) :: boolean()
  def checksum_ok?(frame), do: band(sum(frame), 0xFF) == 0

  defp sum(bytes), do: for(<<b <- bytes>>, reduce: 0, do: (acc -> acc + b))

  @doc """
  Checks and decodes a whole stream frame (header 19 to checksum) that
  should carry the packets `ids`, in order. Returns the decoded packets
  as a map id => value, or why the frame is refused: `:bad_header`,
  `:bad_length` (n is not what `ids` need, or the frame's size does not
  match n), `:bad_packets` (the ids are not the expected ones), `:checksum`.
  """
  @spec parse_frame(binary(), [packet_id()]) ::
          {:ok, %{packet_id() => term()}}
          | {:error, :bad_header | :bad_length | :bad_packets | :checksum}
  def parse_frame(<<@header, n, rest::binary>> = frame, ids) do
    cond do
      n != stream_length(ids) or byte_size(rest) != n + 1 -> {:error, :bad_length}
      not checksum_ok?(frame) -> {:error, :checksum}
      true -> with_ids(binary_part(rest, 0, n), ids, %{})
    end
  end

  def parse_frame(frame, _ids) when is_binary(frame), do: {:error, :bad_header}

  @doc """
  Decodes the packets `ids` laid out as in a stream frame's body (`[id]
  [data]...`) when `with_ids` is true, or as the answer to Query List
  (data only) when it is false.
  """
  @spec parse_packets(binary(), [packet_id()], boolean()) ::
          {:ok, %{packet_id() => term()}} | {:error, :bad_packets}
  def parse_packets(bytes, ids, true), do: with_ids(bytes, ids, %{})

  def parse_packets(bytes, ids, false) do
    Enum.reduce_while(ids, {bytes, %{}}, fn id, {bytes, acc} ->
      with size when is_integer(size) <- packet_size(id),
           <<data::binary-size(size), rest::binary>> <- bytes,
           value when value != :error <- decode(id, data) do
        {:cont, {rest, Map.put(acc, id, value)}}
      else
        _ -> {:halt, :error}
      end
    end)
    |> case do
      {<<>>, acc} -> {:ok, acc}
      _ -> {:error, :bad_packets}
    end
  end

  defp with_ids(<<>>, [], acc), do: {:ok, acc}

  defp with_ids(<<id, rest::binary>>, [id | ids], acc) when is_map_key(@packets, id) do
    size = packet_size(id)

    with <<data::binary-size(size), rest::binary>> <- rest,
         value when value != :error <- decode(id, data) do
      with_ids(rest, ids, Map.put(acc, id, value))
    else
      _ -> {:error, :bad_packets}
    end
  end

  defp with_ids(_bytes, _ids, _acc), do: {:error, :bad_packets}
end
