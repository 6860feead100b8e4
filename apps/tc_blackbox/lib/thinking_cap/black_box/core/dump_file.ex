defmodule ThinkingCap.BlackBox.Core.DumpFile do
  @moduledoc false
  # Writes a ring buffer's entries into one MCAP file, with the
  # recorder's channels (Core.Channels: Foxglove's messages and the whole
  # terms) and times: the log time is the receipt, the publish time the
  # tuple's stamp when it has one.
  alias ThinkingCap.BlackBox.Core.Channels
  alias ThinkingCap.MCAP.Writer

  @spec write(Path.t(), atom(), [{integer(), tuple(), non_neg_integer()}], String.t()) ::
          {:ok, non_neg_integer()} | {:error, term()}
  def write(path, robot, entries, compression) do
    with :ok <- File.mkdir_p(Path.dirname(path)),
         {:ok, w} <- Writer.open(path, compression: compression) do
      case Enum.reduce_while(entries, {:ok, w, Channels.new(robot), 0}, &entry/2) do
        {:ok, w, _chans, n} ->
          with {:ok, _} <- Writer.close(w), do: {:ok, n}

        {:error, reason} ->
          Writer.abandon(w)
          {:error, reason}
      end
    end
  end

  defp entry({time, tuple, _size}, {:ok, w, chans, n}) do
    case Channels.write_tuple(w, chans, tuple, time) do
      {:ok, w, chans, written} -> {:cont, {:ok, w, chans, n + written}}
      {:error, reason, _chans} -> {:halt, {:error, reason}}
    end
  end
end
