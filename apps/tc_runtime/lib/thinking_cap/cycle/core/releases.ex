defmodule ThinkingCap.Cycle.Core.Releases do
  @moduledoc false
  # What the worker reports of each cycle, handled for ThinkingCap.Cycle:
  # a release goes to the activity's owner; an applied command (fresh,
  # the fallback of a missed deadline, or a late result) to the owner and
  # the watchers; both into the activity's statistics (Core.Statistics).

  alias ThinkingCap.Cycle.Core.{Activities, Protocol, Statistics}

  @doc "A release of activity `id`: to its owner, and into its statistics."
  def release(state, id, cycle, {scheduled, released, timer_late}) do
    case state.activities do
      %{^id => a} ->
        # into the statistics first: what the owner was told is there
        # when it asks for timing/0
        Statistics.release(state.statistics, id, scheduled, released, timer_late)
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

        put_in(state.activities[id].release, {cycle, released})

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

        Statistics.applied(state.statistics, id, kind, response)
        Activities.tell(state, a, event)
        state

      _ ->
        state
    end
  end

  # the worker reports a cycle's release before what it applied in it
  defp applied_ns({cycle, released}, cycle, kind, response) when kind != :late,
    do: released + response

  defp applied_ns(_release, _cycle, _kind, _response), do: nil
end
