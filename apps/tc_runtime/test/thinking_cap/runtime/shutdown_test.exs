defmodule ThinkingCap.Runtime.ShutdownTest do
  # A node told to stop whose orderly stop never ends: the watchdog of
  # ThinkingCap.Runtime.Shutdown halts it within the 5 s the node
  # promises, counted from the request, not from when the watchdog starts.
  use ExUnit.Case, async: true

  alias ThinkingCap.Testing.Cluster

  # a process that never lets its supervisor stop it: it traps exits and
  # its terminate/2 does not return
  @hang """
  defmodule ThinkingCap.Runtime.ShutdownTest.Hang do
    use GenServer
    def start_link(_), do: GenServer.start_link(__MODULE__, nil)
    @impl true
    def init(nil) do
      Process.flag(:trap_exit, true)
      {:ok, nil}
    end
    @impl true
    def terminate(_reason, _state), do: Process.sleep(:infinity)
  end
  """

  test "a node whose orderly stop hangs is gone within 5 s of the request" do
    [node] = Cluster.start(1, apps: [:tc_runtime])
    on_exit(fn -> Cluster.stop(node) end)

    [{module, binary}] = Code.compile_string(@hang)
    {:module, ^module} = Cluster.call(node, :code, :load_binary, [module, ~c"hang", binary])

    # under the runtime's own supervisor, shut down with no time limit:
    # the application's stop waits for it for ever
    spec = %{id: :hang, start: {module, :start_link, [nil]}, shutdown: :infinity}

    {:ok, _} =
      Cluster.call(node, Supervisor, :start_child, [ThinkingCap.Runtime.Supervisor, spec])

    os_pid = Cluster.call(node, System, :pid, [])

    asked_at = System.monotonic_time(:millisecond)
    :ok = Cluster.cast(node, :init, :stop, [])

    gone_at =
      Enum.find_value(1..400, fn _ ->
        Process.sleep(20)
        {_, status} = System.cmd("kill", ["-0", os_pid], stderr_to_stdout: true)
        if status != 0, do: System.monotonic_time(:millisecond)
      end)

    assert gone_at, "the node still runs 8 s after the request"
    # the watchdog, not the orderly stop, ended it: not before 4 s
    assert gone_at - asked_at >= 4_000
    assert gone_at - asked_at <= 5_000
  end
end
