defmodule ThinkingCap.MCAP.Core.Decode do
  @moduledoc false
  # The content of MCAP records, parsed by binary patterns only (a field
  # that does not fit its record is an error, never an exception). Fields
  # past those known are ignored, as the specification asks, except for
  # the records it says never grow.

  alias ThinkingCap.MCAP.{Channel, ChunkIndex, Message, Schema, Statistics}

  @type result :: {:ok, term()} | {:error, term()}

  # the next record of `bin` at `pos`: {:ok, op, content, next_pos},
  # :end at the end, {:truncated, pos} when it does not fit
  def next(bin, pos) when pos == byte_size(bin), do: :end

  def next(bin, pos) do
    case bin do
      <<_::binary-size(pos), op, len::little-64, rest::binary>> when len <= byte_size(rest) ->
        {:ok, op, binary_part(rest, 0, len), pos + 9 + len}

      _ ->
        {:truncated, pos}
    end
  end

  def header(
        <<plen::little-32, profile::binary-size(plen), llen::little-32,
          library::binary-size(llen), _::binary>>
      ) do
    with :ok <- utf8(profile),
         :ok <- utf8(library),
         do: {:ok, %{profile: profile, library: library}}
  end

  def header(_), do: {:error, :bad_header}

  def footer(<<summary_start::little-64, summary_offset_start::little-64, crc::little-32>>),
    do:
      {:ok, %{summary_start: summary_start, summary_offset_start: summary_offset_start, crc: crc}}

  def footer(_), do: {:error, :bad_footer}

  def schema(
        <<id::little-16, nlen::little-32, name::binary-size(nlen), elen::little-32,
          encoding::binary-size(elen), dlen::little-32, data::binary-size(dlen), _::binary>>
      ) do
    with :ok <- utf8(name),
         :ok <- utf8(encoding),
         do: {:ok, %Schema{id: id, name: name, encoding: encoding, data: data}}
  end

  def schema(_), do: {:error, :bad_schema}

  def channel(
        <<id::little-16, schema_id::little-16, tlen::little-32, topic::binary-size(tlen),
          elen::little-32, encoding::binary-size(elen), mlen::little-32,
          metadata::binary-size(mlen), _::binary>>
      ) do
    with :ok <- utf8(topic),
         :ok <- utf8(encoding),
         {:ok, metadata} <- string_map(metadata, %{}) do
      {:ok,
       %Channel{
         id: id,
         schema_id: schema_id,
         topic: topic,
         message_encoding: encoding,
         metadata: metadata
       }}
    end
  end

  def channel(_), do: {:error, :bad_channel}

  def message(
        <<channel_id::little-16, sequence::little-32, log_time::little-64,
          publish_time::little-64, data::binary>>
      ),
      do:
        {:ok,
         %Message{
           channel_id: channel_id,
           sequence: sequence,
           log_time: log_time,
           publish_time: publish_time,
           data: data
         }}

  def message(_), do: {:error, :bad_message}

  def chunk(
        <<start_time::little-64, end_time::little-64, usize::little-64, crc::little-32,
          clen::little-32, compression::binary-size(clen), rlen::little-64,
          records::binary-size(rlen), _::binary>>
      ),
      do:
        {:ok,
         %{
           message_start_time: start_time,
           message_end_time: end_time,
           uncompressed_size: usize,
           uncompressed_crc: crc,
           compression: compression,
           records: records
         }}

  def chunk(_), do: {:error, :bad_chunk}

  def message_index(
        <<channel_id::little-16, len::little-32, entries::binary-size(len), _::binary>>
      )
      when rem(len, 16) == 0,
      do:
        {:ok,
         {channel_id, for(<<time::little-64, offset::little-64 <- entries>>, do: {time, offset})}}

  def message_index(_), do: {:error, :bad_message_index}

  def chunk_index(
        <<start_time::little-64, end_time::little-64, offset::little-64, length::little-64,
          olen::little-32, offsets::binary-size(olen), index_length::little-64, clen::little-32,
          compression::binary-size(clen), csize::little-64, usize::little-64, _::binary>>
      )
      when rem(olen, 10) == 0 do
    {:ok,
     %ChunkIndex{
       message_start_time: start_time,
       message_end_time: end_time,
       chunk_start_offset: offset,
       chunk_length: length,
       message_index_offsets:
         Map.new(for <<channel::little-16, at::little-64 <- offsets>>, do: {channel, at}),
       message_index_length: index_length,
       compression: compression,
       compressed_size: csize,
       uncompressed_size: usize
     }}
  end

  def chunk_index(_), do: {:error, :bad_chunk_index}

  def statistics(
        <<messages::little-64, schemas::little-16, channels::little-32, attachments::little-32,
          metadata::little-32, chunks::little-32, start_time::little-64, end_time::little-64,
          clen::little-32, counts::binary-size(clen), _::binary>>
      )
      when rem(clen, 10) == 0 do
    {:ok,
     %Statistics{
       message_count: messages,
       schema_count: schemas,
       channel_count: channels,
       attachment_count: attachments,
       metadata_count: metadata,
       chunk_count: chunks,
       message_start_time: start_time,
       message_end_time: end_time,
       channel_message_counts:
         Map.new(for <<channel::little-16, n::little-64 <- counts>>, do: {channel, n})
     }}
  end

  def statistics(_), do: {:error, :bad_statistics}

  def data_end(<<crc::little-32>>), do: {:ok, crc}
  def data_end(_), do: {:error, :bad_data_end}

  def summary_offset(<<op, start::little-64, length::little-64, _::binary>>),
    do: {:ok, {op, start, length}}

  def summary_offset(_), do: {:error, :bad_summary_offset}

  defp string_map(<<>>, acc), do: {:ok, acc}

  defp string_map(
         <<klen::little-32, k::binary-size(klen), vlen::little-32, v::binary-size(vlen),
           rest::binary>>,
         acc
       ) do
    with :ok <- utf8(k), :ok <- utf8(v), do: string_map(rest, Map.put(acc, k, v))
  end

  defp string_map(_, _acc), do: {:error, :bad_metadata}

  defp utf8(s), do: if(String.valid?(s), do: :ok, else: {:error, :invalid_utf8})
end
