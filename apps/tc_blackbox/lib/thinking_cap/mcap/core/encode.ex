defmodule ThinkingCap.MCAP.Core.Encode do
  @moduledoc false
  # MCAP records as iodata: `<opcode:8><length:64 LE><content>`, every
  # integer little-endian, strings and byte arrays with a length prefix.

  alias ThinkingCap.MCAP.{Channel, ChunkIndex, Schema, Statistics}

  @op_header 0x01
  @op_footer 0x02
  @op_schema 0x03
  @op_channel 0x04
  @op_message 0x05
  @op_chunk 0x06
  @op_message_index 0x07
  @op_chunk_index 0x08
  @op_statistics 0x0B
  @op_summary_offset 0x0E
  @op_data_end 0x0F

  def opcode(:schema), do: @op_schema
  def opcode(:channel), do: @op_channel
  def opcode(:statistics), do: @op_statistics
  def opcode(:chunk_index), do: @op_chunk_index

  # a record and its size in bytes
  def record(op, content) do
    size = IO.iodata_length(content)
    {[op, <<size::little-64>> | content], size + 9}
  end

  def header(profile, library), do: record(@op_header, [string(profile), string(library)])

  def footer(summary_start, summary_offset_start, crc),
    do:
      record(@op_footer, [
        <<summary_start::little-64, summary_offset_start::little-64>>,
        <<crc::little-32>>
      ])

  # the footer up to (without) its CRC, which covers these bytes too
  def footer_head(summary_start, summary_offset_start),
    do: [@op_footer, <<20::little-64, summary_start::little-64, summary_offset_start::little-64>>]

  def schema(%Schema{id: id, name: name, encoding: encoding, data: data}),
    do:
      record(@op_schema, [
        <<id::little-16>>,
        string(name),
        string(encoding),
        <<byte_size(data)::little-32>>,
        data
      ])

  def channel(%Channel{} = c),
    do:
      record(@op_channel, [
        <<c.id::little-16, c.schema_id::little-16>>,
        string(c.topic),
        string(c.message_encoding),
        string_map(c.metadata)
      ])

  # a message record, given the size of its data (the hot path: one
  # binary for the fixed part)
  def message(channel_id, sequence, log_time, publish_time, data, data_size) do
    size = data_size + 22

    {[
       <<@op_message, size::little-64, channel_id::little-16, sequence::little-32,
         log_time::little-64, publish_time::little-64>>
       | data
     ], size + 9}
  end

  def chunk(start_time, end_time, uncompressed_size, crc, compression, records, records_size),
    do:
      record(@op_chunk, [
        <<start_time::little-64, end_time::little-64, uncompressed_size::little-64,
          crc::little-32>>,
        string(compression),
        <<records_size::little-64>>
        | records
      ])

  # entries: [{log_time, offset}]
  def message_index(channel_id, entries) do
    body = for {time, offset} <- entries, do: <<time::little-64, offset::little-64>>
    record(@op_message_index, [<<channel_id::little-16, length(entries) * 16::little-32>> | body])
  end

  def chunk_index(%ChunkIndex{} = c) do
    offsets =
      for {channel, offset} <- Enum.sort(c.message_index_offsets),
          do: <<channel::little-16, offset::little-64>>

    record(@op_chunk_index, [
      <<c.message_start_time::little-64, c.message_end_time::little-64,
        c.chunk_start_offset::little-64, c.chunk_length::little-64>>,
      <<IO.iodata_length(offsets)::little-32>>,
      offsets,
      <<c.message_index_length::little-64>>,
      string(c.compression),
      <<c.compressed_size::little-64, c.uncompressed_size::little-64>>
    ])
  end

  def statistics(%Statistics{} = s) do
    counts =
      for {channel, count} <- Enum.sort(s.channel_message_counts),
          do: <<channel::little-16, count::little-64>>

    record(@op_statistics, [
      <<s.message_count::little-64, s.schema_count::little-16, s.channel_count::little-32,
        s.attachment_count::little-32, s.metadata_count::little-32, s.chunk_count::little-32,
        s.message_start_time::little-64, s.message_end_time::little-64>>,
      <<IO.iodata_length(counts)::little-32>>
      | counts
    ])
  end

  def summary_offset(op, start, length),
    do: record(@op_summary_offset, <<op, start::little-64, length::little-64>>)

  def data_end(crc), do: record(@op_data_end, <<crc::little-32>>)

  defp string(s), do: [<<byte_size(s)::little-32>>, s]

  defp string_map(map) do
    body = for {k, v} <- Enum.sort(map), do: [string(k), string(v)]
    [<<IO.iodata_length(body)::little-32>> | body]
  end
end
