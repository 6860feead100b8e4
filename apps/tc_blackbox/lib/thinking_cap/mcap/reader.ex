defmodule ThinkingCap.MCAP.Reader do
  @moduledoc """
  Reads an MCAP file: every schema, channel and message, with the
  summary's statistics and chunk indexes when it has them.

      {:ok, file} = Reader.read("run.mcap")
      file.mode                    # :indexed or :linear
      for m <- file.messages, do: {file.channels[m.channel_id].topic, m.log_time, m.data}

  **Indexed** when the file ends with a footer whose summary has chunk
  indexes: each chunk is found through its index, decompressed, checked
  against its CRC, and its messages read through its Message Index
  records; messages come in log time order. The summary's CRC and the
  data section's CRC (Data End) are checked too.

  **Linear** otherwise (no summary, or a file cut short by a crash): the
  records are read from the start, chunks decompressed and checked, up
  to the Data End record, the footer, or the last whole record
  (`truncated: true` then: a file whose writer died is valid up to its
  last whole chunk). Messages come in file order.

  Files come from outside, so reading is bounded: the file's size
  (`max_file_bytes`, default 1 GiB), each chunk's uncompressed size
  (`max_chunk_bytes`, default 64 MiB) and all chunks' together
  (`max_total_bytes`, default 1 GiB). Bad input gives `{:error, reason}`,
  never an exception: `:bad_magic`, `{:bad_record, what, offset}`,
  `{:crc, what, offset}`, `{:too_big, what}`, `{:decompress, reason, offset}`,
  `{:unknown_channel, id, offset}`, ...
  """

  alias ThinkingCap.MCAP
  alias ThinkingCap.MCAP.{Channel, ChunkIndex, Compression, Message, Schema, Statistics}
  alias ThinkingCap.MCAP.Core.Decode

  @enforce_keys [:mode]
  defstruct [
    :mode,
    :header,
    :statistics,
    truncated: false,
    schemas: %{},
    channels: %{},
    chunk_indexes: [],
    messages: [],
    chunks: 0,
    data_crc: :absent,
    summary_crc: :absent
  ]

  @typedoc """
  A file read: `mode` says how; `data_crc` and `summary_crc` are `:valid`
  when they were checked, `:absent` when the file has none (zero, or no
  Data End / footer). `chunks` counts the chunks read.
  """
  @type t :: %__MODULE__{
          mode: :indexed | :linear,
          header: %{profile: String.t(), library: String.t()} | nil,
          statistics: Statistics.t() | nil,
          truncated: boolean(),
          schemas: %{pos_integer() => Schema.t()},
          channels: %{non_neg_integer() => Channel.t()},
          chunk_indexes: [ChunkIndex.t()],
          messages: [Message.t()],
          chunks: non_neg_integer(),
          data_crc: :valid | :absent,
          summary_crc: :valid | :absent
        }

  @type option ::
          {:max_file_bytes, pos_integer()}
          | {:max_chunk_bytes, pos_integer()}
          | {:max_total_bytes, pos_integer()}

  @op_header 0x01
  @op_footer 0x02
  @op_schema 0x03
  @op_channel 0x04
  @op_message 0x05
  @op_chunk 0x06
  @op_chunk_index 0x08
  @op_statistics 0x0B
  @op_data_end 0x0F

  import Bitwise, only: [<<<: 2]

  @magic_size 8
  # a footer record: opcode, length, two offsets and a CRC
  @footer_size 1 + 8 + 20

  @doc "Reads the file at `path` (see the moduledoc for the options)."
  @spec read(Path.t(), [option()]) :: {:ok, t()} | {:error, term()}
  def read(path, opts \\ []) do
    max = Keyword.get(opts, :max_file_bytes, 1 <<< 30)

    with {:ok, %File.Stat{size: size}} <- File.stat(path),
         :ok <- if(size <= max, do: :ok, else: {:error, {:too_big, :file}}),
         {:ok, bin} <- File.read(path) do
      read_binary(bin, opts)
    end
  end

  @doc "Reads an MCAP file held in memory."
  @spec read_binary(binary(), [option()]) :: {:ok, t()} | {:error, term()}
  def read_binary(bin, opts \\ []) when is_binary(bin) do
    limits = %{
      chunk: Keyword.get(opts, :max_chunk_bytes, 64 <<< 20),
      total: Keyword.get(opts, :max_total_bytes, 1 <<< 30)
    }

    magic = MCAP.magic()

    case bin do
      <<^magic::binary-size(@magic_size), _::binary>> ->
        with {:ok, header, pos} <- read_header(bin) do
          case footer(bin) do
            {:ok, %{summary_start: start} = footer} when start > 0 ->
              indexed(bin, header, pos, footer, limits)

            _ ->
              linear(bin, pos, %__MODULE__{mode: :linear, header: header}, limits)
          end
        end

      _ ->
        {:error, :bad_magic}
    end
  end

  defp read_header(bin) do
    case Decode.next(bin, @magic_size) do
      {:ok, @op_header, content, pos} ->
        with {:ok, header} <- Decode.header(content), do: {:ok, header, pos}

      _ ->
        {:error, {:bad_record, :header, @magic_size}}
    end
  end

  # the footer, when the file ends with one and the magic
  defp footer(bin) do
    size = byte_size(bin)
    magic = MCAP.magic()
    at = size - @magic_size - @footer_size

    with true <- at >= 2 * @magic_size,
         <<_::binary-size(at), @op_footer, 20::little-64, content::binary-size(20),
           ^magic::binary-size(@magic_size)>> <- bin do
      Decode.footer(content)
    else
      _ -> :none
    end
  end

  ## Indexed

  defp indexed(bin, header, data_start, footer, limits) do
    footer_at = byte_size(bin) - @magic_size - @footer_size

    end_of_summary =
      if footer.summary_offset_start > 0, do: footer.summary_offset_start, else: footer_at

    with :ok <- within(footer.summary_start, end_of_summary, footer_at, :summary),
         :ok <- within(end_of_summary, footer_at, footer_at, :summary_offsets),
         {:ok, summary_crc} <- summary_crc(bin, footer, footer_at),
         {:ok, file} <- summary(bin, footer.summary_start, end_of_summary, header),
         {:ok, data_crc} <- data_crc(bin, footer.summary_start) do
      file = %{file | summary_crc: summary_crc, data_crc: data_crc}

      if file.chunk_indexes == [] do
        # a summary without chunk indexes: the messages are found linearly
        with {:ok, linear} <- linear(bin, data_start, %{file | mode: :linear}, limits),
             do: {:ok, %{linear | summary_crc: summary_crc, data_crc: data_crc}}
      else
        read_chunks(bin, file, limits)
      end
    end
  end

  defp within(from, to, limit, what) do
    if from <= to and to <= limit and from >= @magic_size,
      do: :ok,
      else: {:error, {:bad_record, what, from}}
  end

  defp summary_crc(bin, footer, footer_at) do
    # from the summary's start through the footer's summary_offset_start
    length = footer_at + 1 + 8 + 16 - footer.summary_start

    cond do
      footer.crc == 0 -> {:ok, :absent}
      :erlang.crc32(binary_part(bin, footer.summary_start, length)) == footer.crc -> {:ok, :valid}
      true -> {:error, {:crc, :summary, footer.summary_start}}
    end
  end

  # the Data End record just before the summary, and its CRC
  defp data_crc(bin, summary_start) do
    at = summary_start - 13

    case bin do
      <<_::binary-size(at), @op_data_end, 4::little-64, crc::little-32, _::binary>> when at > 0 ->
        cond do
          crc == 0 -> {:ok, :absent}
          :erlang.crc32(binary_part(bin, 0, at)) == crc -> {:ok, :valid}
          true -> {:error, {:crc, :data, at}}
        end

      _ ->
        {:ok, :absent}
    end
  end

  defp summary(bin, from, to, header) do
    summary_records(binary_part(bin, 0, to), from, %__MODULE__{mode: :indexed, header: header})
  end

  defp summary_records(section, pos, file) do
    case Decode.next(section, pos) do
      :end ->
        {:ok, %{file | chunk_indexes: Enum.reverse(file.chunk_indexes)}}

      {:truncated, pos} ->
        {:error, {:bad_record, :summary, pos}}

      {:ok, op, content, next} ->
        case summary_record(op, content, file) do
          {:ok, file} -> summary_records(section, next, file)
          {:error, what} -> {:error, {:bad_record, what, pos}}
        end
    end
  end

  defp summary_record(@op_schema, content, file) do
    with {:ok, s} <- Decode.schema(content), do: {:ok, put_schema(file, s)}
  end

  defp summary_record(@op_channel, content, file) do
    with {:ok, c} <- Decode.channel(content), do: {:ok, put_channel(file, c)}
  end

  defp summary_record(@op_statistics, content, file) do
    with {:ok, s} <- Decode.statistics(content), do: {:ok, %{file | statistics: s}}
  end

  defp summary_record(@op_chunk_index, content, file) do
    with {:ok, c} <- Decode.chunk_index(content),
         do: {:ok, %{file | chunk_indexes: [c | file.chunk_indexes]}}
  end

  # attachment and metadata indexes, private records: not read
  defp summary_record(_op, _content, file), do: {:ok, file}

  defp read_chunks(bin, file, limits) do
    file.chunk_indexes
    |> Enum.sort_by(&{&1.message_start_time, &1.chunk_start_offset})
    |> Enum.reduce_while({:ok, file, [], 0}, fn index, {:ok, file, acc, total} ->
      case indexed_chunk(bin, index, file, limits, total) do
        {:ok, file, messages, total} -> {:cont, {:ok, file, [messages | acc], total}}
        {:error, _} = error -> {:halt, error}
      end
    end)
    |> case do
      {:ok, file, acc, _total} ->
        messages =
          acc
          |> Enum.reverse()
          |> Enum.concat()
          |> Enum.sort_by(fn {offset, m} -> {m.log_time, offset} end)
          |> Enum.map(&elem(&1, 1))

        {:ok, %{file | messages: messages}}

      error ->
        error
    end
  end

  defp indexed_chunk(bin, %ChunkIndex{} = index, file, limits, total) do
    at = index.chunk_start_offset

    with {:ok, @op_chunk, content, next} <- next_in(bin, at, :chunk),
         true <- next - at == index.chunk_length || {:error, {:bad_record, :chunk_index, at}},
         {:ok, records, total} <- open_chunk(content, at, limits, total),
         {:ok, file} <- chunk_definitions(records, file, at),
         {:ok, messages} <- indexed_messages(bin, index, records, file, at) do
      {:ok, %{file | chunks: file.chunks + 1}, messages, total}
    else
      {:ok, _op, _content, _next} -> {:error, {:bad_record, :chunk_index, at}}
      {:error, _} = error -> error
    end
  end

  defp next_in(bin, at, what) when is_integer(at) and at >= 0 and at < byte_size(bin) do
    case Decode.next(bin, at) do
      {:ok, _op, _content, _next} = ok -> ok
      _ -> {:error, {:bad_record, what, at}}
    end
  end

  defp next_in(_bin, at, what), do: {:error, {:bad_record, what, at}}

  # the schemas and channels a chunk defines
  defp chunk_definitions(records, file, at) do
    fold_records(records, file, at, fn
      @op_schema, content, _offset, file ->
        with {:ok, s} <- Decode.schema(content), do: {:ok, put_schema(file, s)}

      @op_channel, content, _offset, file ->
        with {:ok, c} <- Decode.channel(content), do: {:ok, put_channel(file, c)}

      _op, _content, _offset, file ->
        {:ok, file}
    end)
  end

  # the messages its Message Index records point to: [{position, message}]
  # (all its messages, in order, when it has none)
  defp indexed_messages(_bin, %ChunkIndex{message_index_offsets: none}, records, file, at)
       when map_size(none) == 0 do
    fold_records(records, [], at, fn
      @op_message, content, offset, acc ->
        case Decode.message(content) do
          {:ok, m} ->
            if Map.has_key?(file.channels, m.channel_id),
              do: {:ok, [{{at, offset}, m} | acc]},
              else: {:error, {:unknown_channel, m.channel_id, at}}

          {:error, what} ->
            {:error, what}
        end

      _op, _content, _offset, acc ->
        {:ok, acc}
    end)
  end

  defp indexed_messages(bin, index, records, file, at) do
    index.message_index_offsets
    |> Enum.sort()
    |> Enum.reduce_while({:ok, []}, fn {channel_id, offset}, {:ok, acc} ->
      with {:ok, 0x07, content, _} <- next_in(bin, offset, :message_index),
           {:ok, {^channel_id, entries}} <- Decode.message_index(content),
           {:ok, messages} <- messages_at(records, entries, channel_id, file, at) do
        {:cont, {:ok, [messages | acc]}}
      else
        {:ok, _, _, _} -> {:halt, {:error, {:bad_record, :message_index, offset}}}
        {:ok, {_other, _}} -> {:halt, {:error, {:bad_record, :message_index, offset}}}
        {:error, {:bad_record, _, _}} = error -> {:halt, error}
        {:error, _} -> {:halt, {:error, {:bad_record, :message_index, offset}}}
      end
    end)
    |> case do
      {:ok, acc} -> {:ok, acc |> Enum.concat() |> Enum.map(fn {o, m} -> {{at, o}, m} end)}
      error -> error
    end
  end

  defp messages_at(records, entries, channel_id, file, at) do
    Enum.reduce_while(entries, {:ok, []}, fn {_time, offset}, {:ok, acc} ->
      with {:ok, @op_message, content, _} <- next_in(records, offset, :message),
           {:ok, %Message{channel_id: ^channel_id} = m} <- Decode.message(content),
           true <- Map.has_key?(file.channels, channel_id) do
        {:cont, {:ok, [{offset, m} | acc]}}
      else
        false -> {:halt, {:error, {:unknown_channel, channel_id, at}}}
        _ -> {:halt, {:error, {:bad_record, :message_index, at}}}
      end
    end)
  end

  ## Linear

  defp linear(bin, pos, file, limits) do
    linear(bin, pos, file, limits, [], 0)
  end

  defp linear(bin, pos, file, limits, acc, total) do
    case Decode.next(bin, pos) do
      :end ->
        {:ok, done(file, acc, true)}

      {:truncated, _} ->
        {:ok, done(file, acc, true)}

      {:ok, @op_data_end, content, _next} ->
        with {:ok, crc} <- Decode.data_end(content) do
          cond do
            crc == 0 ->
              {:ok, done(%{file | data_crc: :absent}, acc, false)}

            :erlang.crc32(binary_part(bin, 0, pos)) == crc ->
              {:ok, done(%{file | data_crc: :valid}, acc, false)}

            true ->
              {:error, {:crc, :data, pos}}
          end
        else
          _ -> {:error, {:bad_record, :data_end, pos}}
        end

      {:ok, @op_footer, _content, _next} ->
        {:ok, done(file, acc, false)}

      {:ok, @op_chunk, content, next} ->
        with {:ok, records, total} <- open_chunk(content, pos, limits, total),
             {:ok, {file, acc}} <- fold_records(records, {file, acc}, pos, &plain_record/4) do
          linear(bin, next, %{file | chunks: file.chunks + 1}, limits, acc, total)
        end

      {:ok, op, content, next} ->
        case plain_record(op, content, pos, {file, acc}) do
          {:ok, {file, acc}} -> linear(bin, next, file, limits, acc, total)
          {:error, _} = error -> error
        end
    end
  end

  defp done(file, acc, truncated),
    do: %{file | messages: Enum.reverse(acc), truncated: truncated}

  # a record outside a chunk or in one, read linearly
  defp plain_record(@op_schema, content, pos, {file, acc}) do
    case Decode.schema(content) do
      {:ok, s} -> {:ok, {put_schema(file, s), acc}}
      {:error, _} -> {:error, {:bad_record, :schema, pos}}
    end
  end

  defp plain_record(@op_channel, content, pos, {file, acc}) do
    case Decode.channel(content) do
      {:ok, c} -> {:ok, {put_channel(file, c), acc}}
      {:error, _} -> {:error, {:bad_record, :channel, pos}}
    end
  end

  defp plain_record(@op_message, content, pos, {file, acc}) do
    case Decode.message(content) do
      {:ok, m} ->
        if Map.has_key?(file.channels, m.channel_id),
          do: {:ok, {file, [m | acc]}},
          else: {:error, {:unknown_channel, m.channel_id, pos}}

      {:error, _} ->
        {:error, {:bad_record, :message, pos}}
    end
  end

  defp plain_record(@op_header, _content, pos, _state), do: {:error, {:bad_record, :header, pos}}
  defp plain_record(0, _content, pos, _state), do: {:error, {:bad_record, :opcode, pos}}
  # message indexes, attachments, metadata, private records: skipped
  defp plain_record(_op, _content, _pos, state), do: {:ok, state}

  ## Chunks

  # a chunk's records, decompressed and checked
  defp open_chunk(content, at, limits, total) do
    with {:ok, chunk} <- bad(Decode.chunk(content), :chunk, at),
         :ok <- bounded(chunk.uncompressed_size, limits.chunk, :chunk),
         :ok <- bounded(total + chunk.uncompressed_size, limits.total, :total),
         {:ok, records} <- decompress(chunk, at),
         :ok <- chunk_crc(records, chunk.uncompressed_crc, at) do
      {:ok, records, total + chunk.uncompressed_size}
    end
  end

  defp bad({:ok, _} = ok, _what, _at), do: ok
  defp bad({:error, _}, what, at), do: {:error, {:bad_record, what, at}}

  defp bounded(size, max, _what) when size <= max, do: :ok
  defp bounded(_size, _max, what), do: {:error, {:too_big, what}}

  defp decompress(chunk, at) do
    case Compression.decompress(chunk.compression, chunk.records, chunk.uncompressed_size) do
      {:ok, records} -> {:ok, records}
      {:error, :unsupported} -> {:error, {:compression, chunk.compression, at}}
      {:error, reason} -> {:error, {:decompress, reason, at}}
    end
  end

  defp chunk_crc(_records, 0, _at), do: :ok

  defp chunk_crc(records, crc, at) do
    if :erlang.crc32(records) == crc, do: :ok, else: {:error, {:crc, :chunk, at}}
  end

  # folds `fun.(op, content, offset, acc)` over a chunk's records
  defp fold_records(records, acc, at, fun), do: fold_records(records, 0, acc, at, fun)

  defp fold_records(records, pos, acc, at, fun) do
    case Decode.next(records, pos) do
      :end ->
        {:ok, acc}

      {:truncated, _} ->
        {:error, {:bad_record, :chunk_records, at}}

      {:ok, op, content, next} ->
        case fun.(op, content, pos, acc) do
          {:ok, acc} -> fold_records(records, next, acc, at, fun)
          {:error, {_, _, _} = reason} -> {:error, reason}
          {:error, what} -> {:error, {:bad_record, what, at}}
        end
    end
  end

  defp put_schema(file, %Schema{id: 0}), do: file
  defp put_schema(file, %Schema{id: id} = s), do: %{file | schemas: Map.put(file.schemas, id, s)}

  defp put_channel(file, %Channel{id: id} = c),
    do: %{file | channels: Map.put(file.channels, id, c)}
end
