defmodule ThinkingCap.Runtime.Deployment do
  @moduledoc """
  One node's share of an ADF deployed across the robot's CPUs: every node
  of a release runs one, with the same ADF.

      ThinkingCap.Runtime.deploy("priv/examples/office_two_nodes.adf")
      ThinkingCap.Runtime.Deployment.status()
      ThinkingCap.Runtime.Deployment.move(:control, :brain)

  The ADF's `nodes` define the cluster. A deployment finds its own logical
  name there (the key whose node name is this node's), then:

    * **connects** to every other declared node, and keeps trying every
      `cluster.connect_every` seconds while one is missing. Who is up and
      who is missing is logged on each change and published as
      `{:cluster, robot, %{node:, logical:, up:, missing:, unplaced:}}`
      (one tuple per node, key `{:cluster, robot, node}`);
    * **starts only its own modules**: a module runs on the first node of
      `[node | standby]` that is up (its *host*). A starting node waits up
      to `cluster.settle` seconds for the other nodes (or until all are
      up) before it takes over modules whose nodes are missing, so a node
      that restarts does not snatch its modules back from a standby it has
      not seen yet. A module whose layer gave up on its host
      (`ThinkingCap.Runtime.Supervision`) is not started again, there or
      on a standby, while that host is up: its robot stays stopped until
      `ThinkingCap.Runtime.resume/1`;
    * **fails over**: when a node goes down (crash, power loss, cable),
      each of its modules is started on the first live node of its
      standby list. A module without a live standby is reported in
      `unplaced`. Between the node's death and the standby's start no
      fresh command is produced for that module's activity: the timing
      worker of a node that died applied every fallback as its BEAM went
      (the robot's base stops), and a robot base started anew holds
      `:stop` until a fresh command arrives;
    * **fails back** by policy or by command. `failback: :manual` (the
      default) leaves a module on the standby that took it over until
      `move/2` sends it elsewhere: moving a control module back is an
      operator's decision, made when the robot is in a safe state.
      `failback: :auto` moves it back to the first live node of its list
      as soon as that node is up again (its fallback holds in the gap);
    * **hands state over**: a module that implements
      `c:ThinkingCap.Module.handoff/1` sends its handoff every
      `handoff_every` seconds to the deployments of the other nodes of its
      `[node | standby]`; each keeps the latest, and a module started there
      gets it in `context.handoff`. The state a standby resumes from is at
      most `handoff_every` seconds old (plus the link's delay).

  ## Consistency of placement

  Placement decisions for a module are taken under a `:global` lock on
  that module among the connected nodes, and a node asks every connected
  node's own supervisor (not `:pg`'s eventually consistent view) whether
  the module already runs. So among connected nodes a module runs once.
  A **partition** is the exception, by design: each side sees the other
  as down and runs, on its own side, the modules it can host (a robot's
  CPUs cut off from each other keep doing what they can, each side's
  base stopping on its deadman rule when its commands stop coming). When
  the partition heals, a module found running twice keeps the copy on the
  node that comes first in its `[node | standby]` list; the other copy is
  stopped (its `terminate/2` runs).

  Modules of a deployment must name their node when the ADF declares
  nodes (`node: :local` has no meaning there); an ADF without `nodes`
  deploys everything on this node.
  """
  use GenServer
  require Logger

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.Config.ADF
  alias ThinkingCap.Tuples
  require Tuples

  @typedoc "What `status/0` reports."
  @type status :: %{
          robot: atom(),
          node: node(),
          logical: atom(),
          up: [atom()],
          missing: [atom()],
          modules: %{atom() => node() | nil},
          unplaced: [atom()]
        }

  @doc """
  Starts this node's deployment of `adf` (a path or a `ThinkingCap.Config.ADF`).
  Options: `name` (default `#{inspect(__MODULE__)}`).
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts) do
    GenServer.start_link(__MODULE__, opts, name: Keyword.get(opts, :name, __MODULE__))
  end

  @doc false
  def child_spec(opts),
    do: %{id: __MODULE__, start: {__MODULE__, :start_link, [opts]}, restart: :permanent}

  @doc "This node's view: who is up and missing, where each module runs, what is unplaced."
  @spec status(GenServer.server()) :: status()
  def status(server \\ __MODULE__), do: GenServer.call(server, :status)

  @doc """
  Moves a module to `target` (a logical node of the ADF, or a node name):
  it is stopped where it runs (its fallback holds) and started on the
  target. With `failback: :auto` the module goes back to its preferred
  node on the next change unless the target is that node.
  """
  @spec move(atom(), atom(), GenServer.server()) :: :ok | {:error, term()}
  def move(name, target, server \\ __MODULE__),
    do: GenServer.call(server, {:move, name, target}, 30_000)

  ## Server

  @impl true
  def init(opts) do
    with {:ok, adf} <- Config.adf(Keyword.fetch!(opts, :adf)),
         {:ok, logical} <- whoami(adf),
         :ok <- check_modules(adf) do
      :ok = :net_kernel.monitor_nodes(true)
      # a node is up for this ADF once its deployment runs (connected
      # nodes still booting, or remote shells, host nothing)
      group = {:deployment, adf.robot}
      :ok = :pg.join(Runtime.scope(), group, self())
      {_ref, _members} = :pg.monitor(Runtime.scope(), group)

      state = %{
        adf: adf,
        logical: logical,
        by_node: Map.new(adf.nodes, fn {logical, node} -> {node, logical} end),
        settled: map_size(adf.nodes) == 0,
        announced: false,
        prepared: false,
        reported: nil,
        # the latest handoff of each module, from the node running it
        handoffs: %{}
      }

      send(self(), :tick)
      settle_ms = round(adf.cluster.settle * 1000)
      Process.send_after(self(), :settled, settle_ms)
      {:ok, state}
    else
      {:error, message} ->
        Logger.error("deployment: #{message}")
        {:stop, {:shutdown, message}}
    end
  end

  @impl true
  def handle_call(:status, _from, state), do: {:reply, status_of(state), state}

  def handle_call({:move, name, target}, _from, state) do
    {:reply, do_move(state, name, target), state}
  end

  def handle_call({:handoff, name}, _from, state), do: {:reply, state.handoffs[name], state}

  @impl true
  def handle_info(:tick, state) do
    connect_missing(state)
    Process.send_after(self(), :tick, round(state.adf.cluster.connect_every * 1000))
    {:noreply, reconcile(state)}
  end

  def handle_info(:settled, state), do: {:noreply, reconcile(%{state | settled: true})}

  def handle_info({:nodeup, _node}, state), do: {:noreply, reconcile(state)}
  def handle_info({:nodedown, _node}, state), do: {:noreply, reconcile(state)}

  def handle_info({_ref, change, {:deployment, _robot}, _pids}, state)
      when change in [:join, :leave],
      do: {:noreply, reconcile(state)}

  def handle_info({:tc_handoff, robot, name, handoff}, %{adf: %{robot: robot}} = state),
    do: {:noreply, %{state | handoffs: Map.put(state.handoffs, name, handoff)}}

  def handle_info(_other, state), do: {:noreply, state}

  ## Placement

  # Every module this node should act on: start the ones it hosts that run
  # nowhere, stop its copies that a better node also runs (a healed
  # partition), and with failback: :auto hand a module to its host.
  defp reconcile(state) do
    up = up_nodes(state)
    settled = state.settled or Enum.all?(Map.values(state.adf.nodes), &(&1 in up))
    state = %{state | settled: settled}

    state =
      if settled do
        state = prepare(state)
        for spec <- state.adf.modules, do: place(state, spec, up)
        announce(state)
      else
        state
      end

    report(state, up)
  end

  # Once, before this node starts a module: the recorder ready, so that
  # the modules are traced from their init (Runtime.prepare/2).
  defp prepare(%{prepared: true} = state), do: state

  defp prepare(state) do
    :ok = Runtime.prepare(state.adf, dashboard_node(state.adf) == node())
    %{state | prepared: true}
  end

  # The ADF is announced (the dashboard follows it) by its dashboard's node.
  defp announce(%{announced: true} = state), do: state

  defp announce(state) do
    if dashboard_node(state.adf) == node(), do: Runtime.announce(state.adf)
    %{state | announced: true}
  end

  defp dashboard_node(%ADF{nodes: nodes}) when map_size(nodes) == 0, do: node()

  defp dashboard_node(%ADF{nodes: nodes, dashboard: dashboard}), do: nodes[dashboard[:node]]

  # The lock and the authoritative look at every node are taken only when
  # `:pg`'s (eventually consistent) view says something may need doing.
  defp place(state, spec, up) do
    chain = chain(state, spec)
    host = Enum.find(chain, &(&1 in up))
    ref = ref(state, spec)
    here = Runtime.local_whereis(ref)
    elsewhere = for pid <- Runtime.whereis_all(ref), node(pid) in up, do: node(pid)

    cond do
      # a layer that gave up here stays down until resumed (Runtime.resume/1)
      host == node() and here == nil and
          ThinkingCap.Runtime.Supervision.gave_up?(state.adf.robot, layer(spec)) ->
        :ok

      host == node() and here == nil and (elsewhere == [] or spec.failback == :auto) ->
        locked(ref, fn -> host_here(state, spec, up) end)

      here != nil and node() in chain and
          Enum.any?(Enum.take_while(chain, &(&1 != node())), &(&1 in elsewhere)) ->
        locked(ref, fn -> give_way(ref, chain, up) end)

      true ->
        :ok
    end
  end

  # This node is the module's host: start it unless it runs elsewhere and
  # may stay there (failback :manual), or take it over (failback :auto).
  defp host_here(state, spec, up) do
    ref = ref(state, spec)

    case running_on(ref, up) do
      [] ->
        start_here(state, spec)

      running ->
        if node() not in running and spec.failback == :auto do
          Enum.each(running, &stop_on(&1, ref))
          start_here(state, spec)
        end
    end

    :ok
  end

  # A copy here while a node before this one in the chain also runs it: the
  # partition healed, the better placed copy stays.
  defp give_way({_robot, name} = ref, chain, up) do
    running = running_on(ref, up)
    better = Enum.take_while(chain, &(&1 != node()))

    if node() in running and Enum.any?(running, &(&1 in better)) do
      Logger.warning(
        "deployment: #{name} also runs on #{inspect(Enum.find(running, &(&1 in better)))}; stopping the copy here"
      )

      stop_on(node(), ref)
    end

    :ok
  end

  defp start_here(state, spec) do
    spec = local_spec(state.adf, spec, state.handoffs[spec.name])

    case Runtime.start_here(spec) do
      {:ok, _pid} ->
        Logger.info("deployment: started #{spec.name} on #{node()}")

      {:error, reason} ->
        Logger.error("deployment: #{spec.name} could not start here: #{inspect(reason)}")
    end
  end

  defp do_move(state, name, target) do
    with {:ok, spec} <- find_spec(state, name),
         {:ok, node} <- target_node(state, target) do
      ref = ref(state, spec)

      locked(ref, fn ->
        up = up_nodes(state)

        if node in up do
          Enum.each(running_on(ref, up) -- [node], &stop_on(&1, ref))

          case running_on(ref, [node]) do
            [] -> :erpc.call(node, __MODULE__, :start_moved, [state.adf, spec], 15_000)
            _ -> :ok
          end
        else
          {:error, {:node_down, node}}
        end
      end)
    end
  end

  @doc false
  # Runs on a move's target node.
  def start_moved(adf, spec) do
    spec = local_spec(adf, spec, GenServer.call(__MODULE__, {:handoff, spec.name}))

    case Runtime.start_here(spec) do
      {:ok, _pid} -> :ok
      {:error, reason} -> {:error, reason}
    end
  end

  # What a module started on this node gets beyond its ADF entry: the
  # robot's descriptions, the handoff this node holds for it, and the
  # nodes it hands off to (the rest of its [node | standby]).
  defp local_spec(adf, spec, handoff) do
    Map.merge(spec, %{
      robot: adf.robot,
      rdf: adf.rdf,
      wdf: adf.wdf,
      handoff: handoff,
      handoff_to: Enum.uniq(chain_of(adf, spec)) -- [node()]
    })
  end

  defp find_spec(state, name) do
    case Enum.find(state.adf.modules, &(&1.name == name)) do
      nil -> {:error, {:unknown_module, name}}
      spec -> {:ok, spec}
    end
  end

  defp target_node(state, target) do
    cond do
      Map.has_key?(state.adf.nodes, target) -> {:ok, state.adf.nodes[target]}
      Map.has_key?(state.by_node, target) -> {:ok, target}
      map_size(state.adf.nodes) == 0 and target in [:local, node()] -> {:ok, node()}
      true -> {:error, {:unknown_node, target}}
    end
  end

  # The nodes (running it or not) where the module is hosted right now,
  # asked of each node's own supervisor.
  # this robot's module, by {robot, name}: another robot of the cluster may
  # run a module of the same name
  defp ref(state, spec), do: {state.adf.robot, spec.name}

  defp layer(spec), do: ThinkingCap.Runtime.Supervision.layer_of(spec)

  defp running_on(ref, up) do
    up
    |> :erpc.multicall(Runtime, :local_whereis, [ref], 5_000)
    |> Enum.zip(up)
    |> Enum.flat_map(fn
      {{:ok, pid}, node} when is_pid(pid) -> [node]
      _ -> []
    end)
  end

  defp stop_on(node, ref) do
    :erpc.call(node, Runtime, :stop_here, [ref], 15_000)
  catch
    :error, _ -> :ok
  end

  defp locked(ref, fun) do
    :global.trans({{__MODULE__, ref}, self()}, fun, [node() | Node.list()], 5)
  end

  ## Cluster

  defp chain(state, spec), do: chain_of(state.adf, spec)

  defp chain_of(adf, spec) do
    case map_size(adf.nodes) do
      0 -> [node()]
      _ -> Enum.map([spec.node | spec.standby], &Map.fetch!(adf.nodes, &1))
    end
  end

  defp up_nodes(state) do
    deployed =
      Runtime.scope() |> :pg.get_members({:deployment, state.adf.robot}) |> MapSet.new(&node/1)

    case map_size(state.adf.nodes) do
      0 -> [node()]
      _ -> for node <- Map.values(state.adf.nodes), node in deployed, do: node
    end
  end

  defp connect_missing(state) do
    for node <- Map.values(state.adf.nodes), node != node(), node not in Node.list() do
      Node.connect(node)
    end
  end

  defp status_of(state) do
    up = up_nodes(state)
    running = for node <- up, {name, _} <- local_modules(node), into: %{}, do: {name, node}

    modules = Map.new(state.adf.modules, fn spec -> {spec.name, running[spec.name]} end)

    %{
      robot: state.adf.robot,
      node: node(),
      logical: state.logical,
      up: Enum.map(up, &state.by_node[&1]) |> Enum.reject(&is_nil/1) |> Enum.sort(),
      missing:
        for({logical, node} <- state.adf.nodes, node not in up, do: logical) |> Enum.sort(),
      modules: modules,
      unplaced:
        for(
          spec <- state.adf.modules,
          modules[spec.name] == nil,
          not Enum.any?(chain(state, spec), &(&1 in up)),
          do: spec.name
        )
    }
  end

  defp local_modules(node) do
    :erpc.call(node, Runtime, :local_modules, [], 5_000)
  catch
    :error, _ -> []
  end

  defp report(state, up) do
    status = status_of(state)
    seen = {up, status.unplaced}

    if seen != state.reported do
      unless status.missing == [] do
        Logger.warning(
          "deployment #{state.logical}: missing nodes #{inspect(status.missing)}" <>
            if(status.unplaced == [],
              do: "",
              else: "; modules with no live node: #{inspect(status.unplaced)}"
            )
        )
      end

      cluster =
        Tuples.cluster(
          state.adf.robot,
          Map.take(status, [:node, :logical, :up, :missing, :unplaced])
        )

      # key {:cluster, robot, node}: status.node is this node
      {cluster, opts} = Tuples.keyed(cluster)
      Blackboard.out(cluster, opts)
    end

    %{state | reported: seen}
  end

  ## Set-up

  defp whoami(%ADF{nodes: nodes}) when map_size(nodes) == 0, do: {:ok, :local}

  defp whoami(%ADF{nodes: nodes, file: file}) do
    case Enum.find(nodes, fn {_logical, node} -> node == node() end) do
      {logical, _} ->
        {:ok, logical}

      nil ->
        {:error,
         "#{file}: this node (#{node()}) is not one of the ADF's nodes (#{Enum.map_join(nodes, ", ", fn {l, n} -> "#{l}: #{n}" end)})"}
    end
  end

  defp check_modules(%ADF{nodes: nodes}) when map_size(nodes) == 0, do: :ok

  defp check_modules(%ADF{modules: modules, file: file}) do
    case for(%{node: :local, name: name} <- modules, do: name) do
      [] ->
        :ok

      names ->
        {:error,
         "#{file}: modules #{Enum.map_join(names, ", ", &inspect/1)} must name their node: the ADF declares nodes"}
    end
  end
end
