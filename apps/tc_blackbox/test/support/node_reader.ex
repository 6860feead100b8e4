defmodule ThinkingCap.BlackBox.Test.NodeReader do
  @moduledoc """
  Reads an MCAP file with npm's `@mcap/core` (its indexed reader, the
  library Foxglove uses): runs `test/js/read_mcap.mjs` in Node and
  returns what it printed, decoded (`bin/setup` installs the packages).
  """

  @script Path.expand("../js/read_mcap.mjs", __DIR__)

  @doc "What the Node reader found in `path`: `{:ok, map}` or `{:error, message}`."
  @spec read(Path.t()) :: {:ok, map()} | {:error, String.t()}
  def read(path) do
    node = System.find_executable("node") || raise "node is not installed (bin/setup needs npm)"
    {output, status} = System.cmd(node, [@script, path], stderr_to_stdout: true)

    case {status, decode(output)} do
      {0, %{} = result} -> {:ok, result}
      {_, %{"error" => error}} -> {:error, error}
      _ -> {:error, output}
    end
  end

  defp decode(output) do
    :jiffy.decode(output, [:return_maps])
  catch
    _, _ -> nil
  end
end
