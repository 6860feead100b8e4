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
  #
  # Its queue is bounded. It runs at normal priority, so a node saturated
  # by other work (a simulated fleet on every scheduler) may leave it
  # behind while the cycle keeps sending. Past @max_backlog queued
  # samples (releases, applied results, CPU times) the senders count a
  # sample dropped instead of sending it, so the queue and the node's
  # memory stay bounded and the loss is counted: dropped/0, in
  # ThinkingCap.Cycle.status/0, and a warning at the next publication.
  # Activities added and removed are always sent.
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Cycle.Stats
  alias ThinkingCap.Tuples
  require Tuples

  # timing/0 on a loaded node (a simulated fleet) waits for the events
  # queued before it
  @call_timeout 120_000

  # about 10 MB of queued samples
  @max_backlog 100_000

  # counters shared by the senders and the keeper, made once a node
  @counters {__MODULE__, :counters}
  @backlog 1
  @dropped 2
  @bound 3

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
    do: sample(keeper, {:release, id, scheduled, released, timer_late})

  @doc "What the worker applied (`:fresh`, `:fallback` or `:late`) and the response (ns)."
  def applied(keeper, id, kind, response), do: sample(keeper, {:applied, id, kind, response})

  @doc "The module's own computation of a result (ns), from its host."
  def cpu(id, ns), do: sample(Process.whereis(__MODULE__), {:cpu, id, ns})

  @doc "Samples dropped on this node because the keeper was too far behind."
  def dropped, do: :counters.get(counters(), @dropped)

  @doc false
  # the bound on queued samples (tests lower it); returns the one before
  def max_backlog(n) when is_integer(n) and n >= 0 do
    c = counters()
    before = :counters.get(c, @bound)
    :counters.put(c, @bound, n)
    before
  end

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

  defp sample(nil, _message), do: :ok

  defp sample(keeper, message) do
    c = counters()

    if :counters.get(c, @backlog) >= :counters.get(c, @bound) do
      :counters.add(c, @dropped, 1)
    else
      :counters.add(c, @backlog, 1)
      send(keeper, message)
    end

    :ok
  end

  # made by the first keeper of the node and kept (persistent_term: a
  # later put would make every process check its heap)
  defp counters do
    case :persistent_term.get(@counters, nil) do
      nil ->
        c = :counters.new(3, [:write_concurrency])
        :counters.put(c, @bound, @max_backlog)
        :persistent_term.put(@counters, c)
        c

      c ->
        c
    end
  end

  @impl true
  def init(opts) do
    # the events can come faster than a loaded scheduler runs this
    Process.flag(:message_queue_data, :off_heap)
    publish_ms = Keyword.get(opts, :publish_every)
    if publish_ms, do: :timer.send_interval(publish_ms, :publish)
    # a new keeper's queue is empty, whatever its predecessor left
    :counters.put(counters(), @backlog, 0)
    {:ok, %{}}
  end

  @impl true
  def handle_call(:summaries, _from, state), do: {:reply, summaries(state), state}

  @impl true
  def handle_info({:added, id, name, period_ns}, state),
    do: {:noreply, Map.put(state, id, {name, Stats.new(period_ns)})}

  def handle_info({:removed, id}, state), do: {:noreply, Map.delete(state, id)}

  def handle_info({:release, id, scheduled, released, timer_late}, state) do
    taken()
    update = &(&1 |> Stats.release(scheduled, released) |> Stats.timer(timer_late))
    {:noreply, update(state, id, update)}
  end

  def handle_info({:applied, id, kind, response}, state) do
    taken()
    {:noreply, update(state, id, &Stats.applied(&1, kind, response))}
  end

  def handle_info({:cpu, id, ns}, state) do
    taken()
    {:noreply, update(state, id, &Stats.cpu(&1, ns))}
  end

  def handle_info(:publish, state) do
    warn_dropped()
    wires = ThinkingCap.Cycle.wires()

    for {name, summary} <- summaries(state) do
      wire = Map.delete(wires[name] || %{}, :period_ns)
      {tuple, opts} = Tuples.keyed(Tuples.timing(name, Map.merge(summary, wire)))
      Blackboard.out(tuple, opts)
    end

    {:noreply, state}
  end

  def handle_info(_other, state), do: {:noreply, state}

  defp taken, do: :counters.sub(counters(), @backlog, 1)

  # once a publication, when samples were dropped since the last one
  defp warn_dropped do
    dropped = dropped()
    before = Process.get(:dropped_warned, 0)

    if dropped > before do
      Process.put(:dropped_warned, dropped)

      Logger.warning(
        "timing statistics: #{dropped - before} samples dropped (#{dropped} in all): " <>
          "the node is too busy for its statistics keeper; figures undercount"
      )
    end
  end

  defp update(state, id, fun) do
    case state do
      %{^id => {name, stats}} -> %{state | id => {name, fun.(stats)}}
      _ -> state
    end
  end

  defp summaries(state), do: Map.new(state, fn {_id, {name, s}} -> {name, Stats.summary(s)} end)
end
