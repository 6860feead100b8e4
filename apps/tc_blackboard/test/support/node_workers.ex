defmodule ThinkingCap.Test.NodeWorkers do
  @moduledoc false
  # Processes the multi-node tests start on peer nodes (through
  # Cluster.call), since the test process itself is not on the cluster.

  alias ThinkingCap.Blackboard

  @doc "Starts a process that subscribes to `template` and keeps what it receives."
  def collector(template) do
    parent = self()

    pid =
      spawn(fn ->
        {:ok, ref} = Blackboard.subscribe(template, max_queue: 1_000_000)
        send(parent, {:subscribed, self()})
        collect(ref, [])
      end)

    receive do
      {:subscribed, ^pid} -> pid
    end
  end

  defp collect(ref, acc) do
    receive do
      {:blackboard, ^ref, tuple} ->
        collect(ref, [tuple | acc])

      {:get, from, tag} ->
        send(from, {tag, Enum.reverse(acc)})
        collect(ref, acc)
    end
  end

  @doc "Asks a worker on this node for its result (a collector: what it received, in order)."
  def ask(collector) do
    tag = make_ref()
    send(collector, {:get, self(), tag})

    receive do
      {^tag, tuples} -> tuples
    end
  end

  @doc "Writes `{tag, node(), n}` for each n in `range`."
  def write(tag, range, opts \\ []) do
    for n <- range, do: :ok = Blackboard.out({tag, node(), n}, opts)
    :ok
  end

  @doc """
  Runs `count` takers of `template` that stop once nothing arrives for
  `idle_ms`; returns everything they took. With `report_to`, each taken
  tuple is also sent there at once as `{:taken, node(), tuple}`.
  """
  def take_all(template, count, idle_ms, report_to \\ nil) do
    1..count
    |> Enum.map(fn _ -> Task.async(fn -> take_loop(template, idle_ms, report_to, []) end) end)
    |> Enum.flat_map(&Task.await(&1, :infinity))
  end

  defp take_loop(template, idle_ms, report_to, acc) do
    case Blackboard.take(template, idle_ms) do
      {:ok, tuple} ->
        if report_to, do: send(report_to, {:taken, node(), tuple})
        take_loop(template, idle_ms, report_to, [tuple | acc])

      {:error, :timeout} ->
        acc
    end
  end

  @doc "Writes `{tag, node(), n}` and takes it straight back, for each n."
  def write_and_take(tag, range) do
    for n <- range do
      :ok = Blackboard.out({tag, node(), n})
      {:ok, _} = Blackboard.takep({tag, node(), n})
    end

    :ok
  end

  @doc "Starts a registered process that keeps `{:taken, node, tuple}` reports."
  def report_sink(name) do
    pid = spawn(fn -> sink([]) end)
    Process.register(pid, name)
    pid
  end

  defp sink(acc) do
    receive do
      {:taken, _node, tuple} -> sink([tuple | acc])
      {:get, from, tag} -> send(from, {tag, acc}) && sink(acc)
    end
  end

  @doc "The reports a sink has kept."
  def reports(name), do: ask(Process.whereis(name))

  @doc "Runs a blocking rd or take in the background; `ask/1` waits for its result."
  def start_blocking(op, template, timeout) do
    spawn(fn ->
      result = apply(Blackboard, op, [template, timeout])

      receive do
        {:get, from, tag} -> send(from, {tag, result})
      end
    end)
  end
end
