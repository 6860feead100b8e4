defmodule ThinkingCap.MCAP.Compression do
  @moduledoc """
  The compression of MCAP chunks: `"zstd"` and `"lz4"` (the lz4 frame
  format) through Debian's C libraries, in a NIF (`c_src/tc_mcap.c`,
  built by the app's `Mix.Tasks.Compile.TcMcap` into
  `priv/lib/tc_mcap.so`), and `""`, none.

  Every call runs on a dirty CPU scheduler (a 1 MB chunk takes a few
  milliseconds). Decompression is given the exact size the chunk says it
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

  # the NIF's functions (exported: a NIF replaces them)
  @doc false
  def zstd_compress(_data, _level), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def lz4_compress(_data), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_zstd_decompress(_data, _size), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_lz4_decompress(_data, _size), do: :erlang.nif_error(:nif_not_loaded)
end
