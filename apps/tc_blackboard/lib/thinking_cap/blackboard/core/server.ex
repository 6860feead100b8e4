defmodule ThinkingCap.Blackboard.Core.Server do
  @moduledoc false
  # One per node. Replicates this node's writes and takes to the other
  # nodes' servers (found through :pg), applies theirs, wakes blocked
  # waiters, monitors subscribers and waiters, expires tuples, and resyncs
  # with a peer from a full snapshot whenever either of them (re)joins.
  #
  # All traffic from server A to server B goes over one ordered channel, so
  # B sees A's snapshot, then A's writes and takes, in A's order.
  #
  # The server holds no state that matters beyond its monitors: tuples,
  # subscriptions and waiters are in ETS tables it does not own. A restart
  # rescans waiters, re-monitors, and exchanges snapshots with every peer,
  # which repairs anything that was in its mailbox when it died.

  use GenServer
  require Logger

  alias ThinkingCap.Blackboard.Core.{Store, Subscriptions, Tables, Waiters}

  @scope :thinking_cap_blackboard
  @group :servers
  @sweep_ms 500

  @doc false
  def scope, do: @scope

  @doc false
  def group, do: @group

  def start_link(_opts), do: GenServer.start_link(__MODULE__, :ok, name: __MODULE__)

  @doc false
  # Fire-and-forget message to this node's server. When the server is down
  # the message is dropped: its restart recovers from the tables.
  @spec notify(term()) :: :ok
  def notify(message) do
    case Process.whereis(__MODULE__) do
      nil -> :ok
      pid -> send(pid, message)
    end

    :ok
  end

  @doc false
  # Whether a local write must be passed to the server (peers to replicate
  # to, or blocked waiters to wake).
  @spec wants_out?() :: boolean()
  def wants_out? do
    Waiters.any?() or :ets.lookup_element(Tables.meta(), :peers, 2) > 0
  rescue
    ArgumentError -> false
  end

  @doc false
  # The other nodes' blackboard servers this server replicates to.
  @spec peers() :: [pid()]
  def peers, do: GenServer.call(__MODULE__, :peers)

  ## Callbacks

  @impl true
  def init(:ok) do
    :ok = :pg.join(@scope, @group, self())
    {pg_ref, members} = :pg.monitor(@scope, @group)
    :ok = :net_kernel.monitor_nodes(true)

    state = %{peers: MapSet.new(), monitors: %{}, pg_ref: pg_ref}
    state = Enum.reduce(members, state, &add_peer(&2, &1))
    publish_peer_count(state)

    Waiters.reset()
    state = Enum.reduce(Subscriptions.pids() ++ Waiters.pids(), state, &monitor(&2, &1))
    Waiters.rescan(&Store.exists?/1)
    schedule_sweep()
    {:ok, state}
  end

  @impl true
  def handle_call(:peers, _from, state), do: {:reply, MapSet.to_list(state.peers), state}

  @impl true
  def handle_info({:out, record}, state) do
    {key, tuple, _, _, _} = record
    alive = Store.member?(key)

    unless MapSet.size(state.peers) == 0 do
      message = {:replica_out, node(), Tables.boot_id(), Store.to_wire(record), alive}
      Enum.each(state.peers, &send(&1, message))
    end

    if alive, do: Waiters.arrived(tuple)
    {:noreply, state}
  end

  def handle_info({:replica_out, from, boot, wire, alive}, state) do
    {key, tuple, _, _, _} = wire

    # A node that is no longer connected has been (or is being) purged.
    if from in Node.list() and not Store.member?(key) do
      if alive, do: Store.insert(Store.from_wire(wire))
      Subscriptions.deliver(tuple)
      raise_watermark(from, boot, Store.key_seq(key))
      if alive, do: Waiters.arrived(tuple)
    end

    {:noreply, state}
  end

  def handle_info({:taken, key}, state) do
    Enum.each(state.peers, &send(&1, {:replica_delete, key}))
    {:noreply, state}
  end

  def handle_info({:replica_delete, key}, state) do
    Store.delete(key)
    {:noreply, state}
  end

  def handle_info({:snapshot, from, boot, snapshot}, state) do
    if from in Node.list(), do: apply_snapshot(from, boot, snapshot)
    {:noreply, state}
  end

  def handle_info({:kick, wkey}, state) do
    case Waiters.kicked(wkey, &Store.exists?/1) do
      nil -> {:noreply, state}
      pid -> {:noreply, monitor(state, pid)}
    end
  end

  def handle_info(:rescan, state) do
    Waiters.rescan(&Store.exists?/1)
    {:noreply, state}
  end

  def handle_info({:monitor, pid}, state), do: {:noreply, monitor(state, pid)}

  def handle_info({:DOWN, _mref, :process, pid, _reason}, state) do
    Subscriptions.drop_pid(pid)
    if Waiters.drop_pid(pid), do: Waiters.rescan(&Store.exists?/1)
    {:noreply, %{state | monitors: Map.delete(state.monitors, pid)}}
  end

  def handle_info({ref, :join, @group, pids}, %{pg_ref: ref} = state) do
    {:noreply, Enum.reduce(pids, state, &add_peer(&2, &1))}
  end

  def handle_info({ref, :leave, @group, pids}, %{pg_ref: ref} = state) do
    state = %{state | peers: Enum.reduce(pids, state.peers, &MapSet.delete(&2, &1))}
    publish_peer_count(state)
    {:noreply, state}
  end

  def handle_info({:nodedown, node}, state) do
    purged = Store.purge(node)
    if purged > 0, do: Logger.info("blackboard: #{node} went down, forgot its #{purged} tuples")
    state = %{state | peers: MapSet.reject(state.peers, &(node(&1) == node))}
    publish_peer_count(state)
    {:noreply, state}
  end

  def handle_info({:nodeup, _node}, state), do: {:noreply, state}

  def handle_info(:sweep, state) do
    Store.sweep()
    schedule_sweep()
    {:noreply, demonitor_idle(state)}
  end

  def handle_info(message, state) do
    Logger.warning(
      "blackboard server ignored an unexpected message: #{inspect(message, limit: 20)}"
    )

    {:noreply, state}
  end

  ## Helpers

  # A new peer server gets this node's snapshot before any later write, so
  # its replicas start complete and in order.
  defp add_peer(state, pid) when node(pid) == node(), do: state

  defp add_peer(state, pid) do
    send(pid, {:snapshot, node(), Tables.boot_id(), Store.owned_snapshot()})
    state = %{state | peers: MapSet.put(state.peers, pid)}
    publish_peer_count(state)
    state
  end

  defp publish_peer_count(state),
    do: :ets.insert(Tables.meta(), {:peers, MapSet.size(state.peers)})

  # Records new to this node are delivered to subscribers unless they were
  # delivered before (a partition healing re-sends what was already seen).
  defp apply_snapshot(from, boot, snapshot) do
    new = Store.sync(from, snapshot)
    seen = watermark(from, boot)

    for {_, tuple, _, _, _} = record <- new, Store.seq(record) > seen do
      Subscriptions.deliver(tuple)
      Waiters.arrived(tuple)
    end

    case snapshot do
      [] -> :ok
      _ -> raise_watermark(from, boot, snapshot |> List.last() |> elem(0) |> Store.key_seq())
    end
  end

  defp watermark(from, boot) do
    case :ets.lookup(Tables.meta(), {:watermark, from}) do
      [{_, ^boot, seq}] -> seq
      _ -> 0
    end
  end

  defp raise_watermark(from, boot, seq) do
    if seq > watermark(from, boot),
      do: :ets.insert(Tables.meta(), {{:watermark, from}, boot, seq})
  end

  defp monitor(state, pid) do
    if Map.has_key?(state.monitors, pid) do
      state
    else
      %{state | monitors: Map.put(state.monitors, pid, Process.monitor(pid))}
    end
  end

  defp demonitor_idle(state) do
    active = MapSet.new(Subscriptions.pids() ++ Waiters.pids())

    {idle, busy} =
      Enum.split_with(state.monitors, fn {pid, _} -> not MapSet.member?(active, pid) end)

    Enum.each(idle, fn {_pid, mref} -> Process.demonitor(mref, [:flush]) end)
    %{state | monitors: Map.new(busy)}
  end

  defp schedule_sweep, do: Process.send_after(self(), :sweep, @sweep_ms)
end
