defmodule ThinkingCap.Blackboard.Core.Server do
  @moduledoc false
  # One per node. Applies the other nodes' writes and takes to this node's
  # replicas, replicates this node's takes, wakes blocked waiters, monitors
  # subscribers and waiters, expires tuples, and resyncs with a peer from a
  # full snapshot whenever either of them (re)joins.
  #
  # Writes go to the other nodes' servers through this node's replicator
  # (in each writer's order); takes and snapshots come from the owner's
  # server. Where the two paths race, a tombstone (a delete that
  # overtook its insert) and the snapshot's high-water mark (writes newer
  # than the snapshot that overtook it) keep replicas exact. A new peer is
  # published to writers *before* the snapshot is taken, so every write is
  # either in the snapshot or sent to the peer.
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
  @peer_count Tables.counter(:peers)

  @doc false
  def scope, do: @scope

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
  # The other nodes' blackboard servers that writers replicate to.
  @spec peers() :: [pid()]
  def peers do
    :ets.lookup_element(Tables.meta(), :peers, 2)
  rescue
    ArgumentError -> []
  end

  @doc false
  # Passes a take of an owned tuple on to the other nodes (called by the
  # taker, after its ets:take). With no peer published there is nobody to
  # tell: a peer published later gets a snapshot taken after it, which no
  # longer holds the tuple.
  @spec taken(tuple()) :: :ok
  def taken(key) do
    if :counters.get(Tables.counters(), @peer_count) > 0, do: notify({:taken, key})
    :ok
  end

  @doc false
  # Passes a local write on to every other node (called by the writer).
  @spec replicate(Store.record(), :counters.counters_ref()) :: :ok
  def replicate(record, counters \\ Tables.counters()) do
    if :counters.get(counters, @peer_count) > 0 do
      case peers() do
        [] -> :ok
        peers -> ThinkingCap.Blackboard.Core.Replicator.replicate(peers, record)
      end
    end

    :ok
  end

  ## Callbacks

  @impl true
  def init(:ok) do
    :ok = :pg.join(@scope, @group, self())
    {pg_ref, members} = :pg.monitor(@scope, @group)
    :ok = :net_kernel.monitor_nodes(true)

    state = %{peers: MapSet.new(), monitors: %{}, pg_ref: pg_ref}
    publish_peers(state)
    state = Enum.reduce(members, state, &add_peer(&2, &1))

    Waiters.reset()
    state = Enum.reduce(Subscriptions.pids() ++ Waiters.pids(), state, &monitor(&2, &1))
    Waiters.rescan(&Store.first_match/1)
    schedule_sweep()
    {:ok, state}
  end

  @impl true
  def handle_info({:arrived, tuple}, state) do
    Waiters.arrived(tuple)
    {:noreply, state}
  end

  def handle_info({:replica_out, from, boot, wire, alive}, state) do
    {key, tuple, _, _, _} = wire

    # A node that is no longer connected has been (or is being) purged; a
    # record already here came with a snapshot and was delivered then.
    if from in Node.list() and not Store.member?(key) do
      stored = alive and not Store.tombstoned?(key)
      # stored before it is delivered: a subscriber can read what it is sent
      if stored, do: Store.insert(Store.from_wire(wire))
      Subscriptions.deliver(tuple)
      if stored and Waiters.any?(), do: Waiters.arrived(tuple)
      raise_watermark(from, boot, Store.key_seq(key))
    end

    {:noreply, state}
  end

  def handle_info({:taken, key}, state) do
    Enum.each(state.peers, &send(&1, {:replica_delete, key}))
    {:noreply, state}
  end

  def handle_info({:replica_delete, key}, state) do
    Store.delete_replica(key)
    {:noreply, state}
  end

  def handle_info({:snapshot, from, boot, high, snapshot}, state) do
    if from in Node.list(), do: apply_snapshot(from, boot, high, snapshot)
    {:noreply, state}
  end

  def handle_info({:kick, wkey}, state) do
    case Waiters.kicked(wkey, &Store.first_match/1) do
      nil -> {:noreply, state}
      pid -> {:noreply, monitor(state, pid)}
    end
  end

  def handle_info(:rescan, state) do
    Waiters.rescan(&Store.first_match/1)
    {:noreply, state}
  end

  def handle_info({:monitor, pid}, state), do: {:noreply, monitor(state, pid)}

  def handle_info({:DOWN, _mref, :process, pid, _reason}, state) do
    Subscriptions.drop_pid(pid)
    if Waiters.drop_pid(pid), do: Waiters.rescan(&Store.first_match/1)
    {:noreply, %{state | monitors: Map.delete(state.monitors, pid)}}
  end

  def handle_info({ref, :join, @group, pids}, %{pg_ref: ref} = state) do
    {:noreply, Enum.reduce(pids, state, &add_peer(&2, &1))}
  end

  def handle_info({ref, :leave, @group, pids}, %{pg_ref: ref} = state) do
    state = %{state | peers: Enum.reduce(pids, state.peers, &MapSet.delete(&2, &1))}
    publish_peers(state)
    {:noreply, state}
  end

  def handle_info({:nodedown, node}, state) do
    purged = Store.purge(node)
    if purged > 0, do: Logger.info("blackboard: #{node} went down, forgot its #{purged} tuples")
    state = %{state | peers: MapSet.reject(state.peers, &(node(&1) == node))}
    publish_peers(state)
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

  # A new peer is published to writers first, then sent this node's
  # snapshot: a write is in the snapshot or sent after it was published.
  defp add_peer(state, pid) when node(pid) == node(), do: state

  defp add_peer(state, pid) do
    state = %{state | peers: MapSet.put(state.peers, pid)}
    publish_peers(state)
    high = Store.high_water()
    send(pid, {:snapshot, node(), Tables.boot_id(), high, Store.owned_snapshot()})
    state
  end

  defp publish_peers(state) do
    :ets.insert(Tables.meta(), {:peers, MapSet.to_list(state.peers)})
    :counters.put(Tables.counters(), @peer_count, MapSet.size(state.peers))
  end

  # Records new to this node are delivered to subscribers unless they were
  # delivered before (a partition healing re-sends what was already seen).
  defp apply_snapshot(from, boot, high, snapshot) do
    new = Store.sync(from, high, snapshot)
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
