defmodule ThinkingCap.Dashboard.Test.StopProbe do
  @moduledoc """
  Watches, on a node about to stop, when its web server (yaws' server
  process) goes down, and writes to a file whether the node's robots had
  been stopped by then (`ThinkingCap.Runtime.Shutdown.begun?/0`).
  """

  @doc """
  Starts a process that monitors yaws' server; when it goes down, writes
  `"robots stopped first"` or `"web server stopped first"` to `path`.
  """
  @spec watch(Path.t()) :: pid()
  def watch(path) do
    parent = self()

    pid =
      spawn(fn ->
        ref = Process.monitor(:yaws_server)
        send(parent, :watching)

        receive do
          {:DOWN, ^ref, _, _, _} ->
            first =
              if ThinkingCap.Runtime.Shutdown.begun?(),
                do: "robots stopped first",
                else: "web server stopped first"

            # written whole, then named: the test waits for the name
            File.write!(path <> ".part", first)
            File.rename!(path <> ".part", path)
        end
      end)

    receive do
      :watching -> pid
    end
  end
end
