defmodule ThinkingCap.Cycle.Core.Activities do
  @moduledoc false
  # The activities ThinkingCap.Cycle holds, in its state: ids by name (an
  # id is kept for a name for good, so a module restarted gets its slot
  # back), each activity's owner and wire, and the processes watching each
  # name. Every applied command goes to the owner and the watchers
  # (tell/3). Their statistics are Core.Statistics'.

  alias ThinkingCap.Cycle.Core.{Protocol, Statistics, Worker}

  @doc "Adds an activity (or adds it again: its wire is kept on both sides) and tells the worker."
  def add(state, name, owner, period, deadline, lead, priority, fallback) do
    {id, state} = id_for(state, name)
    Process.monitor(owner)

    # added again: the worker keeps its wire, and so does this side
    old = Map.get(state.activities, id, %{})

    activity = %{
      id: id,
      name: name,
      period_ns: round(period * 1.0e9),
      deadline_ns: round(deadline * 1.0e9),
      lead_ns: round(lead * 1.0e9),
      priority: priority,
      fallback: fallback,
      owner: owner,
      wire: Map.get(old, :wire),
      wire_errors: Map.get(old, :wire_errors, 0),
      # the last release: {cycle, released_ns}
      release: nil
    }

    Worker.command(state.port, Protocol.add(activity))
    Statistics.added(state.statistics, id, name, activity.period_ns)
    put_in(state.activities[id], activity)
  end

  @doc "The names of the activities held now."
  def names(state),
    do: Map.keys(state.ids) |> Enum.filter(&Map.has_key?(state.activities, state.ids[&1]))

  @doc """
  The live process that owns activity `name`, if any (a restarted
  module's predecessor may be dead before its DOWN arrives).
  """
  def live_owner(state, name) do
    with %{^name => id} <- state.ids,
         %{owner: pid} <- state.activities[id],
         true <- Process.alive?(pid) do
      pid
    else
      _ -> nil
    end
  end

  @doc "The id of activity `name` if it is held now."
  def id_of(state, name) do
    case state.ids do
      %{^name => id} when is_map_key(state.activities, id) -> {:ok, id}
      _ -> :error
    end
  end

  @doc "Sends `pid` every command applied for `name` from now on."
  def watch(state, name, pid) do
    Process.monitor(pid)
    watchers = Map.update(state.watchers, name, MapSet.new([pid]), &MapSet.put(&1, pid))
    %{state | watchers: watchers}
  end

  @doc "A process is gone: the activities it owned (removed by `remove`) and its watches."
  def down(state, pid, remove) do
    state =
      Enum.reduce(state.activities, state, fn
        {_id, %{owner: ^pid, name: name}}, st -> remove.(st, name)
        _other, st -> st
      end)

    watchers =
      for {name, pids} <- state.watchers,
          pids = MapSet.delete(pids, pid),
          MapSet.size(pids) > 0,
          into: %{},
          do: {name, pids}

    %{state | watchers: watchers}
  end

  @doc "An applied command goes to the activity's owner and its watchers."
  def tell(state, a, event) do
    message = {:tc_cycle, :applied, a.name, event}
    send(a.owner, message)

    for pid <- Map.get(state.watchers, a.name, []), pid != a.owner, do: send(pid, message)
    :ok
  end

  @doc "An activity's wire (its device or nil), its wire's errors and its period."
  def wire(a),
    do: %{wire: a.wire && a.wire.device, wire_errors: a.wire_errors, period_ns: a.period_ns}

  defp id_for(state, name) do
    case state.ids do
      %{^name => id} ->
        {id, state}

      _ ->
        {state.next_id,
         %{state | ids: Map.put(state.ids, name, state.next_id), next_id: state.next_id + 1}}
    end
  end
end
