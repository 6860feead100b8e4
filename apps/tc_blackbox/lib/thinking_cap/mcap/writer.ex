defmodule ThinkingCap.MCAP.Writer do
  @moduledoc """
  Writes an MCAP file (`ThinkingCap.MCAP` shows the layout): a value the
  caller threads through its calls, holding the open file (or, with
  `new/1`, memory) and the chunk being filled.

      {:ok, w} = Writer.open("run.mcap", compression: "zstd")
      {:ok, schema, w} = Writer.add_schema(w, "foxglove.LaserScan", "jsonschema", schema_json)
      {:ok, channel, w} = Writer.add_channel(w, schema, "/r1/laser", "json")
      {:ok, w} = Writer.add_message(w, channel, log_time, publish_time, json)
      {:ok, _bytes} = Writer.close(w)

  Schema, Channel and Message records go into the open chunk, kept in C
  (`ThinkingCap.MCAP.Compression.stream/1`, which makes the Message
  records and their index entries itself; `add_messages/3` a list of
  them in one call), so that a chunk's records are not kept on the heap; the chunk is compressed once, when it ends. A chunk is
  closed and written, with a Message Index per channel after it, when it
  holds `chunk_bytes` (`add_message/6` says so) or when the caller asks
  (`close_chunk/1`, the recorder's timer): one write per chunk, so the
  file on disk is valid up to its last whole chunk whatever happens to
  the process. `close/1` writes the Data End record, the
  summary (schemas, channels, statistics, chunk indexes), the summary
  offsets and the footer.

  The file is opened `:raw`: only the process that opened it may write.
  """

  alias ThinkingCap.MCAP
  alias ThinkingCap.MCAP.{Channel, ChunkIndex, Compression, Schema, Statistics}
  alias ThinkingCap.MCAP.Core.Encode

  @default_chunk_bytes 1_048_576

  defstruct [
    :sink,
    :compression,
    :chunk_bytes,
    offset: 0,
    crc: 0,
    schemas: [],
    channels: [],
    next_schema: 1,
    next_channel: 0,
    # the open chunk: its stream (Compression.stream/1), which holds its
    # records, their size and time span and their index entries
    stream: nil,
    # for the summary
    chunk_indexes: [],
    stats: %Statistics{}
  ]

  @opaque t :: %__MODULE__{}

  @typedoc """
  Options: `compression` (`"zstd"`, `"lz4"` or `""`; default `"zstd"`),
  `chunk_bytes` (the uncompressed size at which a chunk closes, default
  #{@default_chunk_bytes}), `library` (the Header's, default
  `"thinkingcap"`).
  """
  @type option ::
          {:compression, String.t()} | {:chunk_bytes, pos_integer()} | {:library, String.t()}

  @doc "Opens `path` (created or truncated) and writes the magic and the Header."
  @spec open(Path.t(), [option()]) :: {:ok, t()} | {:error, term()}
  def open(path, opts \\ []) do
    with {:ok, w} <- init(opts),
         {:ok, fd} <- :file.open(path, [:raw, :binary, :write]) do
      start(%{w | sink: {:file, fd}}, opts)
    end
  end

  @doc "A writer into memory: `close/1` returns the file's bytes."
  @spec new([option()]) :: {:ok, t()} | {:error, term()}
  def new(opts \\ []) do
    with {:ok, w} <- init(opts), do: start(%{w | sink: {:memory, []}}, opts)
  end

  defp init(opts) do
    compression = Keyword.get(opts, :compression, "zstd")
    chunk_bytes = Keyword.get(opts, :chunk_bytes, @default_chunk_bytes)

    cond do
      compression not in Compression.algorithms() ->
        {:error, {:compression, compression}}

      not (is_integer(chunk_bytes) and chunk_bytes > 0) ->
        {:error, {:chunk_bytes, chunk_bytes}}

      true ->
        {:ok,
         %__MODULE__{
           compression: compression,
           chunk_bytes: chunk_bytes,
           stream: Compression.stream(compression)
         }}
    end
  end

  defp start(w, opts) do
    {header, _} = Encode.header("", Keyword.get(opts, :library, "thinkingcap"))
    write(w, [MCAP.magic() | header])
  end

  @doc """
  Adds a schema (written into the open chunk, and the summary); returns
  its id (1, 2, ...).
  """
  @spec add_schema(t(), String.t(), String.t(), binary()) :: {:ok, pos_integer(), t()}
  def add_schema(%__MODULE__{} = w, name, encoding, data)
      when is_binary(name) and is_binary(encoding) and is_binary(data) do
    schema = %Schema{id: w.next_schema, name: name, encoding: encoding, data: data}
    w = put_record(w, Encode.schema(schema))
    {:ok, schema.id, %{w | schemas: [schema | w.schemas], next_schema: w.next_schema + 1}}
  end

  @doc """
  Adds a channel on `schema_id` (0: none); returns its id (0, 1, ...).
  `metadata` is a map of strings.
  """
  @spec add_channel(t(), non_neg_integer(), String.t(), String.t(), map()) ::
          {:ok, non_neg_integer(), t()}
  def add_channel(%__MODULE__{} = w, schema_id, topic, message_encoding, metadata \\ %{})
      when is_integer(schema_id) and is_binary(topic) and is_binary(message_encoding) do
    channel = %Channel{
      id: w.next_channel,
      schema_id: schema_id,
      topic: topic,
      message_encoding: message_encoding,
      metadata: metadata
    }

    w = put_record(w, Encode.channel(channel))
    {:ok, channel.id, %{w | channels: [channel | w.channels], next_channel: w.next_channel + 1}}
  end

  @doc """
  Adds a message (`data` is iodata) to the open chunk. When the chunk then
  holds `chunk_bytes` it is closed and written. `sequence` `:next` is the
  channel's next in the file (1, 2, ...).
  """
  @spec add_message(
          t(),
          non_neg_integer(),
          MCAP.time(),
          MCAP.time(),
          iodata(),
          non_neg_integer() | :next
        ) :: {:ok, t()} | {:error, term()}
  def add_message(%__MODULE__{} = w, channel_id, log_time, publish_time, data, sequence \\ 0) do
    # the hot path: the record is made and kept in C, the writer unchanged
    size = Compression.message(w.stream, channel_id, sequence, log_time, publish_time, data)
    if size >= w.chunk_bytes, do: close_chunk(w), else: {:ok, w}
  end

  @doc """
  Adds messages, `[{channel_id, sequence, log_time, publish_time, data}]`
  (as `add_message/6`'s, in order), their records made in one call; the
  chunk is closed and written whenever it holds `chunk_bytes`, as with
  `add_message/6`. `bytes` is about as many bytes as their data (a hint:
  more than 1 MB go on a dirty scheduler).
  """
  @spec add_messages(t(), [Compression.message()], non_neg_integer()) ::
          {:ok, t()} | {:error, term()}
  def add_messages(%__MODULE__{} = w, [], _bytes), do: {:ok, w}

  def add_messages(%__MODULE__{} = w, messages, bytes) do
    case Compression.messages(w.stream, messages, w.chunk_bytes, bytes) do
      {size, _written} when size < w.chunk_bytes ->
        {:ok, w}

      {_size, written} ->
        with {:ok, w} <- close_chunk(w),
             do: add_messages(w, Enum.drop(messages, written), bytes)
    end
  end

  @doc """
  Adds tuples held as their external terms (`t:Compression.held/0`: the
  black box recorder's), in order, each as its Foxglove messages (their
  JSON made in C from the term) then its term, as `add_message/6` would
  with `:next` sequences; the chunk is closed and written whenever it
  holds `chunk_bytes`. Stops at a tuple whose JSON C leaves to the
  caller: returns it and those after it, unwritten, with the count of
  messages written.
  """
  @spec add_held(t(), [Compression.held()]) ::
          {:ok, t(), non_neg_integer(), [Compression.held()]} | {:error, term()}
  def add_held(%__MODULE__{} = w, tuples), do: add_held(w, tuples, 0, 0)

  defp add_held(w, [], _skip, n), do: {:ok, w, n, []}

  defp add_held(w, tuples, skip, n) do
    {size, done, partial, written} = Compression.held(w.stream, tuples, w.chunk_bytes, skip)
    rest = Enum.drop(tuples, done)

    if size >= w.chunk_bytes do
      with {:ok, w} <- close_chunk(w), do: add_held(w, rest, partial, n + written)
    else
      {:ok, w, n + written, rest}
    end
  end

  @doc "Bytes in the open chunk (uncompressed)."
  @spec chunk_size(t()) :: non_neg_integer()
  def chunk_size(%__MODULE__{stream: stream}), do: elem(Compression.size(stream), 0)

  @doc "Bytes written so far (the open chunk not counted)."
  @spec bytes_written(t()) :: non_neg_integer()
  def bytes_written(%__MODULE__{offset: offset}), do: offset

  @doc "Messages added so far."
  @spec message_count(t()) :: non_neg_integer()
  def message_count(%__MODULE__{stats: stats, stream: stream}),
    do: stats.message_count + elem(Compression.size(stream), 1)

  @doc """
  Closes the open chunk, if it holds anything: compresses it and writes it
  with its message indexes in one write.
  """
  @spec close_chunk(t()) :: {:ok, t()} | {:error, term()}
  def close_chunk(%__MODULE__{} = w) do
    if chunk_size(w) == 0, do: {:ok, w}, else: write_chunk(w)
  end

  defp write_chunk(w) do
    chunk = Compression.finish(w.stream)
    %{compressed: compressed, start_time: start_time, end_time: end_time} = chunk

    {record, chunk_length} =
      Encode.chunk(
        start_time,
        end_time,
        chunk.size,
        chunk.crc,
        w.compression,
        [compressed],
        byte_size(compressed)
      )

    at = w.offset + chunk_length
    offsets = Map.new(chunk.channels, fn {channel, _n, offset} -> {channel, at + offset} end)

    chunk_index = %ChunkIndex{
      message_start_time: start_time,
      message_end_time: end_time,
      chunk_start_offset: w.offset,
      chunk_length: chunk_length,
      message_index_offsets: offsets,
      message_index_length: byte_size(chunk.indexes),
      compression: w.compression,
      compressed_size: byte_size(compressed),
      uncompressed_size: chunk.size
    }

    stats = count(w.stats, chunk.channels, start_time, end_time)

    w = %{
      w
      | chunk_indexes: [chunk_index | w.chunk_indexes],
        stats: %{stats | chunk_count: stats.chunk_count + 1}
    }

    write(w, [record, chunk.indexes])
  end

  # channels: [{channel, messages, _}]
  defp count(stats, channels, start_time, end_time) do
    {n, counts} =
      Enum.reduce(channels, {0, stats.channel_message_counts}, fn {channel, k, _}, {n, counts} ->
        {n + k, Map.update(counts, channel, k, &(&1 + k))}
      end)

    cond do
      n == 0 ->
        stats

      stats.message_count == 0 ->
        %{
          stats
          | message_count: n,
            channel_message_counts: counts,
            message_start_time: start_time,
            message_end_time: end_time
        }

      true ->
        %{
          stats
          | message_count: stats.message_count + n,
            channel_message_counts: counts,
            message_start_time: min(stats.message_start_time, start_time),
            message_end_time: max(stats.message_end_time, end_time)
        }
    end
  end

  @doc """
  Closes the open chunk and writes the Data End record, the summary and
  the footer; closes the file. Returns the bytes written (for a file) or
  the file's bytes (for memory).
  """
  @spec close(t()) :: {:ok, non_neg_integer() | binary()} | {:error, term()}
  def close(%__MODULE__{} = w) do
    with {:ok, w} <- close_chunk(w),
         {:ok, w} <- write(w, elem(Encode.data_end(w.crc), 0)),
         {:ok, w} <- write_summary(w) do
      finish(w)
    else
      {:error, _} = error ->
        abandon(w)
        error
    end
  end

  @doc "Closes the file as it stands (valid up to its last whole chunk), writing nothing more."
  @spec abandon(t()) :: :ok
  def abandon(%__MODULE__{sink: {:file, fd}}), do: _ = :file.close(fd)
  def abandon(%__MODULE__{}), do: :ok

  defp write_summary(w) do
    summary_start = w.offset
    schemas = Enum.reverse(w.schemas)
    channels = Enum.reverse(w.channels)

    stats = %{
      w.stats
      | schema_count: length(schemas),
        channel_count: length(channels)
    }

    groups = [
      {Encode.opcode(:schema), Enum.map(schemas, &Encode.schema/1)},
      {Encode.opcode(:channel), Enum.map(channels, &Encode.channel/1)},
      {Encode.opcode(:statistics), [Encode.statistics(stats)]},
      {Encode.opcode(:chunk_index),
       Enum.map(Enum.reverse(w.chunk_indexes), &Encode.chunk_index/1)}
    ]

    {summary, offsets, at} =
      Enum.reduce(groups, {[], [], summary_start}, fn
        {_op, []}, acc ->
          acc

        {op, records}, {summary, offsets, at} ->
          length = Enum.reduce(records, 0, fn {_, size}, n -> n + size end)
          {offset, _} = Encode.summary_offset(op, at, length)
          {[summary, Enum.map(records, &elem(&1, 0))], [offsets, offset], at + length}
      end)

    summary_offset_start = at
    head = Encode.footer_head(summary_start, summary_offset_start)
    crc = :erlang.crc32([summary, offsets, head])

    {footer, _} = Encode.footer(summary_start, summary_offset_start, crc)
    write(w, [summary, offsets, footer, MCAP.magic()])
  end

  defp finish(%__MODULE__{sink: {:file, fd}, offset: offset}) do
    case :file.close(fd) do
      :ok -> {:ok, offset}
      error -> error
    end
  end

  defp finish(%__MODULE__{sink: {:memory, acc}}),
    do: {:ok, acc |> Enum.reverse() |> IO.iodata_to_binary()}

  defp put_record(w, {record, size}) do
    :ok = Compression.add(w.stream, record, size)
    w
  end

  defp write(%__MODULE__{sink: {:file, fd}} = w, data) do
    case :file.write(fd, data) do
      :ok -> {:ok, advance(w, data)}
      {:error, _} = error -> error
    end
  end

  defp write(%__MODULE__{sink: {:memory, acc}} = w, data),
    do: {:ok, %{advance(w, data) | sink: {:memory, [data | acc]}}}

  defp advance(w, data),
    do: %{w | offset: w.offset + IO.iodata_length(data), crc: :erlang.crc32(w.crc, data)}
end
