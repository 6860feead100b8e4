defmodule ThinkingCap.MCAP.Compression do
  @moduledoc """
  The compression of MCAP chunks: `"zstd"` and `"lz4"` (the lz4 frame
  format) through Debian's C libraries, in a NIF (`c_src/tc_mcap.c`,
  built by the app's `Mix.Tasks.Compile.TcMcap` into
  `priv/lib/tc_mcap.so`), and `""`, none.

  A whole buffer's compression and decompression, and a chunk stream's
  end, run on a dirty CPU scheduler (a 1 MB chunk takes a few
  milliseconds); a chunk stream takes its records on a normal one.
  Decompression is given the exact size the chunk says it
  holds and never makes more: a corrupt or lying input gives
  `{:error, reason}`.
  """

  @on_load :load_nif

  # zstd's level: 3 is its default; 1 costs about half the CPU for a few
  # per cent more bytes on the recorder's JSON
  @zstd_level 1

  @typedoc "A chunk's compression, as MCAP names it."
  @type algorithm :: String.t()

  defp load_nif do
    path = :filename.join(:code.priv_dir(:tc_blackbox), ~c"lib/tc_mcap")
    :erlang.load_nif(path, 0)
  end

  @doc "The algorithms this build reads and writes."
  @spec algorithms() :: [algorithm()]
  def algorithms, do: ["", "zstd", "lz4"]

  @doc "Compresses `data` with `algorithm` (one of `algorithms/0`)."
  @spec compress(algorithm(), iodata()) :: binary()
  def compress("", data), do: IO.iodata_to_binary(data)
  def compress("zstd", data), do: zstd_compress(data, @zstd_level)
  def compress("lz4", data), do: lz4_compress(data)

  @doc """
  Decompresses `data`, which must give exactly `size` bytes. Returns
  `{:error, :unsupported}` for an algorithm this build does not know,
  `{:error, :corrupt}` or `{:error, :size_mismatch}` for bad data.
  """
  @spec decompress(algorithm(), binary(), non_neg_integer()) ::
          {:ok, binary()} | {:error, :unsupported | :corrupt | :size_mismatch | :no_memory}
  def decompress("", data, size) when byte_size(data) == size, do: {:ok, data}
  def decompress("", _data, _size), do: {:error, :size_mismatch}

  def decompress("zstd", data, size) when is_binary(data) and is_integer(size) and size >= 0,
    do: nif_zstd_decompress(data, size)

  def decompress("lz4", data, size) when is_binary(data) and is_integer(size) and size >= 0,
    do: nif_lz4_decompress(data, size)

  def decompress(_other, _data, _size), do: {:error, :unsupported}

  @typedoc "A chunk being compressed as its records come (`stream/1`)."
  @opaque stream :: reference()

  # what one call of add/2 runs on a normal scheduler; more goes to a dirty one
  @normal_max 65_536

  @doc """
  A stream that takes a chunk's records as they come (`add/3`,
  `message/6`) and keeps them off the heap, in C; `finish/1` compresses
  the chunk, once, and ends it. The records need not be kept until the
  chunk closes, and no call on a normal scheduler takes long.
  """
  @spec stream(algorithm()) :: stream()
  def stream(""), do: chunk_new(0, @zstd_level)
  def stream("zstd"), do: chunk_new(1, @zstd_level)
  def stream("lz4"), do: chunk_new(2, @zstd_level)

  @doc "Adds records, `data` (`size` bytes), to the chunk."
  @spec add(stream(), iodata(), non_neg_integer()) :: :ok
  def add(stream, data, size) when size <= @normal_max, do: chunk_add(stream, data)
  def add(stream, data, _size), do: chunk_add_dirty(stream, data)

  @doc """
  Adds a Message record to the chunk: its header made here, its sequence
  `sequence`, or with `:next` the channel's next (1, 2, ... in the
  stream), and its entry in the chunk's message indexes. Returns the
  chunk's size so far (uncompressed).
  """
  @spec message(
          stream(),
          non_neg_integer(),
          non_neg_integer() | :next,
          non_neg_integer(),
          non_neg_integer(),
          iodata()
        ) :: non_neg_integer()
  def message(stream, channel, sequence, log_time, publish_time, data) do
    sequence = if sequence == :next, do: -1, else: sequence

    if is_binary(data) and byte_size(data) > @normal_max,
      do: chunk_message_dirty(stream, channel, sequence, log_time, publish_time, data),
      else: chunk_message(stream, channel, sequence, log_time, publish_time, data)
  end

  @typedoc "A message for `messages/4`: channel, sequence, log time, publish time, data."
  @type message ::
          {non_neg_integer(), non_neg_integer() | :next, non_neg_integer(), non_neg_integer(),
           iodata()}

  # what one call of messages/3 copies on a normal scheduler (about
  # 100 µs); a dirty one's switch costs tens of µs, more than copying
  # a list of tuples' records
  @messages_normal_max 1_048_576

  @doc """
  Adds Message records to the chunk, in the list's order, as `message/6`
  does each, in one call, until the chunk holds `limit` bytes (the
  message that reaches it is written); `bytes` is about as many bytes
  as they hold (more than 1 MB: the call runs on a dirty scheduler).
  Returns the chunk's size so far (uncompressed) and how many were
  written.
  """
  @spec messages(stream(), [message()], non_neg_integer(), non_neg_integer()) ::
          {non_neg_integer(), non_neg_integer()}
  def messages(stream, messages, limit, bytes) when bytes <= @messages_normal_max,
    do: chunk_messages(stream, messages, limit)

  def messages(stream, messages, limit, _bytes),
    do: chunk_messages_dirty(stream, messages, limit)

  @typedoc """
  A tuple held as its external term, for `held/4`: its Foxglove
  messages' channels, its term's channel (nil: the term not written),
  log time, publish time, kind (`ThinkingCap.BlackBox.Foxglove.kind/1`)
  and external term.
  """
  @type held ::
          {[non_neg_integer()], non_neg_integer() | nil, non_neg_integer(), non_neg_integer(),
           atom(), binary()}

  @doc """
  Adds tuples held as their external terms (the recorder's), in the
  list's order, in one call: each one's Foxglove messages, their JSON
  made here from the term (as `ThinkingCap.BlackBox.Core.JSON.Native`
  makes it), then its term, each as `message/6` with the channel's next
  sequence; until the chunk holds `limit` bytes (the message that
  reaches it is written) or a tuple comes whose JSON C leaves to the
  caller. `skip`: messages of the first tuple written already. Returns
  the chunk's size so far, the tuples written whole, the messages
  written of the next one, and the messages written in this call.
  """
  @spec held(stream(), [held()], non_neg_integer(), non_neg_integer()) ::
          {non_neg_integer(), non_neg_integer(), non_neg_integer(), non_neg_integer()}
  def held(stream, tuples, limit, skip), do: chunk_held(stream, tuples, limit, skip)

  @doc "The open chunk's size (uncompressed) and its messages."
  @spec size(stream()) :: {non_neg_integer(), non_neg_integer()}
  def size(stream), do: chunk_size(stream)

  @typedoc """
  An ended chunk: its compressed bytes, the CRC-32 and size of its
  records, its messages' first and last log times (0 when none), its
  Message Index records (one per channel, by channel, entries in log
  time order) and, by channel, its messages and where its Message Index
  begins in them.
  """
  @type chunk :: %{
          compressed: binary(),
          crc: non_neg_integer(),
          size: non_neg_integer(),
          start_time: non_neg_integer(),
          end_time: non_neg_integer(),
          indexes: binary(),
          channels: [{non_neg_integer(), pos_integer(), non_neg_integer()}]
        }

  @doc """
  Ends the chunk (compresses it, on a dirty scheduler). The stream is
  then empty, for the next chunk; the channels' sequences go on.
  """
  @spec finish(stream()) :: chunk()
  def finish(stream) do
    {compressed, crc, size, start_time, end_time, indexes, channels} = chunk_finish(stream)

    %{
      compressed: compressed,
      crc: crc,
      size: size,
      start_time: start_time,
      end_time: end_time,
      indexes: indexes,
      channels: channels
    }
  end

  # the NIF's functions (exported: a NIF replaces them)
  @doc false
  def zstd_compress(_data, _level), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def lz4_compress(_data), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_zstd_decompress(_data, _size), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_lz4_decompress(_data, _size), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_new(_algorithm, _level), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_add(_stream, _data), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_add_dirty(_stream, _data), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_message(_stream, _channel, _sequence, _log, _publish, _data),
    do: :erlang.nif_error(:nif_not_loaded)

  @doc false
  def chunk_message_dirty(_stream, _channel, _sequence, _log, _publish, _data),
    do: :erlang.nif_error(:nif_not_loaded)

  @doc false
  def chunk_messages(_stream, _messages, _limit), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_messages_dirty(_stream, _messages, _limit), do: :erlang.nif_error(:nif_not_loaded)

  @doc false
  def chunk_held(_stream, _tuples, _limit, _skip), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_size(_stream), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def chunk_finish(_stream), do: :erlang.nif_error(:nif_not_loaded)
end
