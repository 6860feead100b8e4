defmodule ThinkingCap.Cycle.Core.Releases do
  @moduledoc false
  # What the worker reports of each cycle, handled for ThinkingCap.Cycle:
  # a release goes to the activity's owner; an applied command (fresh,
  # the fallback of a missed deadline, or a late result) to the owner and
  # the watchers; both, and the module's CPU time, into the activity's
  # statistics.

  alias ThinkingCap.Cycle.Core.{Activities, Protocol}
  alias ThinkingCap.Cycle.Stats

  @doc "A release of activity `id`: to its owner, and into its statistics."
  def release(state, id, cycle, {scheduled, released, timer_late}) do
    case state.activities do
      %{^id => a} ->
        # released lead_ns early: the owner waits for the scheduled instant
        send(
          a.owner,
          {:tc_cycle, :release, a.name,
           %{
             id: id,
             cycle: cycle,
             scheduled_ns: scheduled + a.lead_ns,
             released_ns: released,
             timer_late_ns: timer_late
           }}
        )

        stats = a.stats |> Stats.release(scheduled, released) |> Stats.timer(timer_late)
        a = %{a | stats: stats, release: {cycle, released}}
        put_in(state.activities[id], a)

      _ ->
        state
    end
  end

  @doc "A command the worker applied for activity `id` (or a late result it did not)."
  def applied(state, id, %{cycle: cycle, kind: kind, response_ns: response} = frame) do
    case state.activities do
      %{^id => a} ->
        event = %{
          cycle: cycle,
          kind: kind,
          command: Protocol.command(frame.command),
          wired: frame.wired,
          response_us: response / 1000,
          applied_ns: applied_ns(a.release, cycle, kind, response)
        }

        Activities.tell(state, a, event)
        put_in(state.activities[id].stats, Stats.applied(a.stats, kind, response))

      _ ->
        state
    end
  end

  @doc "The module's own computation of a result of activity `id` (ns)."
  def cpu(state, id, ns) do
    case state.activities do
      %{^id => a} -> put_in(state.activities[id].stats, Stats.cpu(a.stats, ns))
      _ -> state
    end
  end

  # the worker reports a cycle's release before what it applied in it
  defp applied_ns({cycle, released}, cycle, kind, response) when kind != :late,
    do: released + response

  defp applied_ns(_release, _cycle, _kind, _response), do: nil
end
