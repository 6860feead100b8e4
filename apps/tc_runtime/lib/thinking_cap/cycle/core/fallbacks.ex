defmodule ThinkingCap.Cycle.Core.Fallbacks do
  @moduledoc false
  # The fallbacks this side tells of, the worker having applied them (or
  # no worker applying anything): an activity removed (its module stopped
  # or crashed), and every activity when the worker died. A missed
  # deadline's fallback is the worker's own report (Core.Releases).

  alias ThinkingCap.Cycle.Core.{Activities, Protocol, Statistics, Worker}

  @doc """
  Removes activity `name`: the worker applies its fallback (its fallback
  bytes on its wire, if any); its subscribers hear it here, since the
  activity is gone when the worker's frame arrives.
  """
  def remove(state, name) do
    case Activities.id_of(state, name) do
      {:ok, id} ->
        a = state.activities[id]
        Worker.command(state.port, Protocol.remove(id))

        # what the worker does: the fallback bytes on the wire, if any
        Activities.tell(state, a, %{
          cycle: 0,
          kind: :fallback,
          command: a.fallback,
          wired: state.port != nil and a.wire != nil,
          response_us: 0.0,
          applied_ns: nil
        })

        Statistics.removed(state.statistics, id)
        %{state | activities: Map.delete(state.activities, id)}

      :error ->
        state
    end
  end

  @doc """
  The worker died: it applies nothing, so every activity's fallback holds
  from now (its owner drives it), before a new worker is even spawned.
  """
  def worker_died(state) do
    for {_id, a} <- state.activities,
        do:
          Activities.tell(state, a, %{
            cycle: 0,
            kind: :fallback,
            command: a.fallback,
            wired: false,
            response_us: 0.0,
            applied_ns: nil
          })

    :ok
  end
end
