defmodule ThinkingCap.Cycle.Core.Statistics do
  @moduledoc false
  # The activities' timing statistics (ThinkingCap.Cycle.Stats), kept
  # here and not in ThinkingCap.Cycle, through which every release passes.
  # A node's statistics take about 250 words an activity, a megabyte for
  # a simulated fleet of 200 activities: in the cycle's heap they made
  # each of its garbage collections copy them, and OTP collects a heap of
  # 128K words or more on a dirty scheduler, which the release then waits
  # for. Here they cost the cycle one small message an event. This process
  # runs at normal priority, publishes the statistics on the blackboard
  # and answers ThinkingCap.Cycle.timing/0.
  #
  # The cycle starts it, linked; when it dies the cycle starts another
  # and names its activities again (their figures start anew).
  use GenServer

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Cycle.Stats
  alias ThinkingCap.Tuples
  require Tuples

  # timing/0 on a loaded node (a simulated fleet) waits for the events
  # queued before it
  @call_timeout 120_000

  @doc "Starts it, linked to the caller, with `:publish_every` ms (nil: never)."
  def start_link(opts), do: GenServer.start_link(__MODULE__, opts, name: __MODULE__)

  # The cycle tells `keeper` (the pid it holds: no name lookup on the
  # release path; a keeper gone meanwhile takes nothing), hosts find it
  # by name.

  @doc "An activity added (or added again: its figures start anew)."
  def added(keeper, id, name, period_ns), do: tell(keeper, {:added, id, name, period_ns})

  @doc "An activity removed."
  def removed(keeper, id), do: tell(keeper, {:removed, id})

  @doc "A release: scheduled and released (ns), the worker's timer late by `timer_late` ns."
  def release(keeper, id, scheduled, released, timer_late),
    do: tell(keeper, {:release, id, scheduled, released, timer_late})

  @doc "What the worker applied (`:fresh`, `:fallback` or `:late`) and the response (ns)."
  def applied(keeper, id, kind, response), do: tell(keeper, {:applied, id, kind, response})

  @doc "The module's own computation of a result (ns), from its host."
  def cpu(id, ns), do: tell(Process.whereis(__MODULE__), {:cpu, id, ns})

  @doc """
  Each activity's summary (`ThinkingCap.Cycle.Stats.summary/1`), by name;
  empty while the keeper is restarted. A keeper behind a long queue of
  events (a loaded node) answers when it has taken them.
  """
  def summaries do
    GenServer.call(__MODULE__, :summaries, @call_timeout)
  catch
    :exit, {:timeout, _} = reason -> exit(reason)
    :exit, _ -> %{}
  end

  defp tell(nil, _message), do: :ok

  defp tell(keeper, message) do
    send(keeper, message)
    :ok
  end

  @impl true
  def init(opts) do
    # the events can come faster than a loaded scheduler runs this
    Process.flag(:message_queue_data, :off_heap)
    publish_ms = Keyword.get(opts, :publish_every)
    if publish_ms, do: :timer.send_interval(publish_ms, :publish)
    {:ok, %{}}
  end

  @impl true
  def handle_call(:summaries, _from, state), do: {:reply, summaries(state), state}

  @impl true
  def handle_info({:added, id, name, period_ns}, state),
    do: {:noreply, Map.put(state, id, {name, Stats.new(period_ns)})}

  def handle_info({:removed, id}, state), do: {:noreply, Map.delete(state, id)}

  def handle_info({:release, id, scheduled, released, timer_late}, state),
    do:
      {:noreply,
       update(state, id, &(&1 |> Stats.release(scheduled, released) |> Stats.timer(timer_late)))}

  def handle_info({:applied, id, kind, response}, state),
    do: {:noreply, update(state, id, &Stats.applied(&1, kind, response))}

  def handle_info({:cpu, id, ns}, state), do: {:noreply, update(state, id, &Stats.cpu(&1, ns))}

  def handle_info(:publish, state) do
    wires = ThinkingCap.Cycle.wires()

    for {name, summary} <- summaries(state) do
      wire = Map.delete(wires[name] || %{}, :period_ns)
      {tuple, opts} = Tuples.keyed(Tuples.timing(name, Map.merge(summary, wire)))
      Blackboard.out(tuple, opts)
    end

    {:noreply, state}
  end

  def handle_info(_other, state), do: {:noreply, state}

  defp update(state, id, fun) do
    case state do
      %{^id => {name, stats}} -> %{state | id => {name, fun.(stats)}}
      _ -> state
    end
  end

  defp summaries(state), do: Map.new(state, fn {_id, {name, s}} -> {name, Stats.summary(s)} end)
end
