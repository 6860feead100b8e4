defmodule ThinkingCap.Testing.Cluster do
  @moduledoc """
  Real local BEAM nodes for tests and benchmarks, started with OTP's
  `:peer`.

      nodes = Cluster.start(3)              # three connected nodes running the blackboard
      Cluster.call(hd(nodes), ThinkingCap.Blackboard, :out, [{:job, 1}])
      Cluster.partition(a, b)               # cut the a-b link; both keep running
      Cluster.heal(a, b)
      Cluster.stop(nodes)

  By default each node is controlled over its standard I/O, not over
  Erlang distribution, so the test's own VM need not be a node, and cutting
  the links between nodes never cuts the test off from them. Nodes run with
  `dist_auto_connect once`: a link that was cut stays cut until `heal/2`.
  `connection: :dist` instead connects the nodes to the calling node
  (which must be alive), for benchmarks that message them directly.
  """

  alias ThinkingCap.Blackboard.Core.Server

  defstruct [:peer, :node, :connection]

  @type t :: %__MODULE__{peer: pid(), node: node(), connection: :standard_io | :dist}

  @type option ::
          {:apps, [atom()]}
          | {:connection, :standard_io | :dist}
          | {:connect, boolean()}
          | {:log_level, Logger.level()}
          | {:names, [atom()]}
          | {:cookie, atom()}
          | {:max_fds, pos_integer()}

  @doc """
  Starts `count` nodes, starts `apps` (default `[:tc_blackboard]`) on each
  and, unless `connect: false`, connects them all to each other and waits
  until their blackboards replicate to each other.

  `names:` gives the nodes' short names (they run on host 127.0.0.1;
  default: random names), so a test can write them into an ADF or start a
  killed node again under its name; `cookie:` joins nodes started earlier
  (`cookie/1` tells theirs); `max_fds:` runs them under that many file
  descriptors (`ulimit -n`), to see what running out of them does.
  """
  @spec start(pos_integer(), [option()]) :: [t()]
  def start(count, opts \\ []) do
    connection = Keyword.get(opts, :connection, :standard_io)
    default_cookie = if connection == :dist, do: Node.get_cookie(), else: random_cookie()
    cookie = Keyword.get(opts, :cookie, default_cookie)
    names = Keyword.get_lazy(opts, :names, fn -> for _ <- 1..count, do: random_name() end)
    nodes = for name <- Enum.take(names, count), do: start_node(connection, cookie, opts, name)

    if Keyword.get(opts, :connect, true) do
      for a <- nodes, b <- nodes, a.node < b.node, do: true = connect(a, b)
      if :tc_blackboard in Keyword.get(opts, :apps, [:tc_blackboard]), do: await_mesh(nodes)
    end

    nodes
  end

  @doc "A fresh short node name for `start/2`'s `names:`."
  @spec random_name() :: atom()
  def random_name, do: List.to_atom(:peer.random_name(~c"tc"))

  @doc "The full node name `start/2` gives a node of short name `name`."
  @spec node_name(atom()) :: node()
  def node_name(name), do: :"#{name}@127.0.0.1"

  @doc "The cookie of a started node, for `start/2`'s `cookie:`."
  @spec cookie(t()) :: atom()
  def cookie(node), do: call(node, Node, :get_cookie, [])

  defp start_node(connection, cookie, opts, name) do
    name = Atom.to_charlist(name)
    level = opts |> Keyword.get(:log_level, :warning) |> Atom.to_charlist()

    # A node's emulator flags (no busy-waiting), and schedulers left at
    # normal priority (the runtime would put them at SCHED_FIFO): on a
    # 2-core machine a peer's scheduler was seen spinning at real-time
    # priority after another node of its cluster was killed, starving
    # the whole machine.
    args =
      [~c"-setcookie", Atom.to_charlist(cookie), ~c"-kernel", ~c"dist_auto_connect", ~c"once"] ++
        ThinkingCap.VMFlags.charlists() ++
        [~c"-logger", ~c"level", level] ++
        [~c"-tc_runtime", ~c"beam_priority", ~c"nil", ~c"-pa" | :code.get_path()]

    spec = %{name: name, host: ~c"127.0.0.1", longnames: true, args: args}

    spec =
      case opts[:max_fds] do
        nil ->
          spec

        n ->
          erl = System.find_executable("erl")
          script = ~c"ulimit -n #{n} && exec #{erl} \"$@\""
          Map.put(spec, :exec, {~c"/bin/sh", [~c"-c", script, ~c"sh"]})
      end

    # Without a :connection the peer is controlled over distribution.
    spec = if connection == :dist, do: spec, else: Map.put(spec, :connection, :standard_io)
    {:ok, peer, node} = :peer.start(spec)

    handle = %__MODULE__{peer: peer, node: node, connection: connection}

    for app <- Keyword.get(opts, :apps, [:tc_blackboard]) do
      {:ok, _} = call(handle, Application, :ensure_all_started, [app])
    end

    handle
  end

  defp random_cookie,
    do: :"tc_#{System.unique_integer([:positive])}_#{:rand.uniform(1_000_000_000)}"

  @doc "Calls `apply(m, f, a)` on the node and returns the result."
  @spec call(t(), module(), atom(), list(), timeout()) :: term()
  def call(node, m, f, a, timeout \\ 15_000)

  def call(%__MODULE__{connection: :dist, node: node}, m, f, a, timeout),
    do: :erpc.call(node, m, f, a, timeout)

  def call(%__MODULE__{peer: peer}, m, f, a, timeout), do: :peer.call(peer, m, f, a, timeout)

  @doc "Runs `apply(m, f, a)` on the node without waiting for it."
  @spec cast(t(), module(), atom(), list()) :: :ok
  def cast(%__MODULE__{connection: :dist, node: node}, m, f, a), do: :erpc.cast(node, m, f, a)
  def cast(%__MODULE__{peer: peer}, m, f, a), do: :peer.cast(peer, m, f, a)

  @doc "Connects two nodes (Erlang distribution)."
  @spec connect(t(), t()) :: boolean()
  def connect(a, b), do: call(a, :net_kernel, :connect_node, [b.node])

  @doc "Cuts the link between two nodes and waits until both see it cut."
  @spec partition(t(), t()) :: :ok
  def partition(a, b) do
    call(a, :erlang, :disconnect_node, [b.node])

    wait_until(fn ->
      b.node not in call(a, Node, :list, []) and a.node not in call(b, Node, :list, [])
    end)
  end

  @doc "Reconnects two nodes and waits until their blackboards replicate again."
  @spec heal(t(), t()) :: :ok
  def heal(a, b) do
    true = connect(a, b)
    await_mesh([a, b])
  end

  @doc "Kills a node at once, as a crash or power loss would."
  @spec kill(t()) :: :ok
  def kill(%__MODULE__{} = node) do
    ref = Process.monitor(node.peer)
    cast(node, :erlang, :halt, [137])

    receive do
      {:DOWN, ^ref, :process, _, _} -> :ok
    after
      10_000 -> :peer.stop(node.peer)
    end
  end

  @doc "Stops nodes (ignores nodes that are already gone)."
  @spec stop(t() | [t()]) :: :ok
  def stop(nodes) when is_list(nodes), do: Enum.each(nodes, &stop/1)

  def stop(%__MODULE__{peer: peer}) do
    if Process.alive?(peer), do: :peer.stop(peer)
    :ok
  catch
    :exit, _ -> :ok
  end

  @doc "Waits until every node's blackboard server replicates to all the others."
  @spec await_mesh([t()]) :: :ok
  def await_mesh(nodes) do
    wait_until(fn ->
      Enum.all?(nodes, fn n ->
        peers = n |> call(Server, :peers, []) |> Enum.map(&node/1)
        Enum.all?(nodes, &(&1.node == n.node or &1.node in peers))
      end)
    end)
  end

  @doc """
  Polls `fun` every 10 ms until it returns a truthy value, for at most
  `timeout` ms; raises if it never does.
  """
  @spec wait_until((() -> term()), timeout()) :: :ok
  def wait_until(fun, timeout \\ 10_000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    do_wait_until(fun, deadline)
  end

  defp do_wait_until(fun, deadline) do
    cond do
      fun.() ->
        :ok

      System.monotonic_time(:millisecond) > deadline ->
        raise "condition not reached in time: #{inspect(fun)}"

      true ->
        Process.sleep(10)
        do_wait_until(fun, deadline)
    end
  end
end
