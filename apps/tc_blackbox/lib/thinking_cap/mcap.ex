defmodule ThinkingCap.MCAP do
  @moduledoc """
  MCAP files: the open container format for timestamped messages that
  Foxglove and the ROS 2 tools read (the MCAP specification, major
  version 0). `ThinkingCap.MCAP.Writer` writes them, `ThinkingCap.MCAP.Reader`
  reads them back; both are pure Elixir but for the chunk compression
  (`ThinkingCap.MCAP.Compression`, a NIF on Debian's libzstd and liblz4).

  A file written here is laid out as

      magic Header
      Chunk MessageIndex...   (Schema, Channel and Message records in chunks)
      Chunk MessageIndex...
      DataEnd                 (the CRC of everything before it)
      Schema... Channel... Statistics ChunkIndex...   (the summary)
      SummaryOffset...
      Footer magic            (the CRC of the summary)

  Chunks are written whole, one write each, so a file cut short (the VM
  killed, the disk full) is valid up to its last whole chunk: the reader
  reads such a file linearly. Times are `uint64` nanoseconds; the recorder
  uses nanoseconds since the Unix epoch.
  """

  @typedoc "Nanoseconds (the recorder's: since the Unix epoch)."
  @type time :: non_neg_integer()

  @doc "The eight bytes that open and close every MCAP file."
  @spec magic() :: binary()
  def magic, do: <<0x89, "MCAP0\r\n">>
end
