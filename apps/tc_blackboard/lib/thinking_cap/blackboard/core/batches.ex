defmodule ThinkingCap.Blackboard.Core.Batches do
  @moduledoc false
  # Batched subscriptions (`subscribe(t, batch: true)`): their tuples are
  # held in a table and sent in lists, `{:blackboard_batch, ref, [{tuple,
  # at}]}`, by this process, one per node, when `max_batch` are held or
  # `max_delay_ms` after the first, so that a subscriber that takes many
  # tuples a second is woken once a list and not once a tuple.
  #
  # A writer (`hold/2`) takes the subscription's next position (one
  # update_counter on its row of `Tables.batches/0`, which reads the
  # position sent last in the same step) and inserts the tuple there in
  # `Tables.batched/0`, with the monotonic time. Positions are dense, and a
  # writer inserts before it takes its next: so this process sends only
  # the positions that follow the last one sent without a gap, in order,
  # and the tuples of one writer come in the order written, whichever
  # tuples of other writers it races with (a select that a racing insert
  # slips behind shows a gap, and the rest waits for the next list).
  #
  # The writer that holds the first tuple after the last list tells this
  # process (a timer of `max_delay_ms`), and the one that holds the
  # `max_batch`th too (sent at once). With `max_queue` held, a writer
  # marks its position dropped instead (the subscription's policy applies).
  # A list is not sent while the subscriber's mailbox holds
  # `max_queue / max_batch` messages: its tuples stay held, and count.
  #
  # A writer killed between taking a position and inserting leaves a gap
  # that never fills (and may not have told this process): every
  # `@gap_ms` it looks for subscriptions holding tuples with no timer
  # armed, and a gap still there `@gap_ms` after it was first seen is
  # passed over. The tables belong to `Tables`: a restart of this
  # process loses nothing held, and arms a timer for every subscription
  # holding tuples. A list sent just before this process died may be sent
  # again (its tuples are forgotten once sent).

  use GenServer

  alias ThinkingCap.Blackboard.Core.Tables

  @gap_ms 1_000
  # tuples a writer inserted after the subscription was closed
  @sweep_ms 1_000

  @doc false
  def start_link(_opts), do: GenServer.start_link(__MODULE__, :ok, name: __MODULE__)

  @doc false
  # A batched subscription's row; before its subscription row is inserted.
  @spec open(reference(), pid(), {pos_integer(), pos_integer()}, pos_integer()) :: true
  def open(ref, pid, {max_batch, max_delay_ms}, max_queue),
    do: :ets.insert(Tables.batches(), {ref, 0, 0, pid, max_batch, max_delay_ms, max_queue})

  @doc false
  # Forgets a batched subscription and the tuples held for it.
  @spec close(reference()) :: :ok
  def close(ref) do
    :ets.delete(Tables.batches(), ref)
    forget(ref)
    notify({:closed, ref})
  end

  @doc false
  # Holds `tuple` for the batched subscription `ref`: :ok, or :full when
  # `max_queue` tuples are held already (it is not).
  @spec hold(reference(), tuple()) :: :ok | :full
  def hold(ref, tuple) do
    [position, sent, max_batch, max_queue] =
      :ets.update_counter(Tables.batches(), ref, [{2, 1}, {3, 0}, {5, 0}, {7, 0}])

    held = position - sent

    if held > max_queue do
      :ets.insert(Tables.batched(), {{ref, position}, :dropped, 0})
      :full
    else
      :ets.insert(Tables.batched(), {{ref, position}, tuple, :erlang.monotonic_time()})

      cond do
        held == max_batch -> notify({:full, ref})
        held == 1 -> notify({:pending, ref})
        true -> :ok
      end

      :ok
    end
  rescue
    # closed meanwhile
    ArgumentError -> :ok
  end

  @doc false
  # Sends what is held for `ref` now; when it returns, the lists are in
  # the subscriber's mailbox (this process sent them before it answered).
  @spec flush_now(reference()) :: :ok
  def flush_now(ref), do: GenServer.call(__MODULE__, {:flush, ref}, :infinity)

  defp notify(message) do
    case Process.whereis(__MODULE__) do
      nil -> :ok
      pid -> send(pid, message)
    end

    :ok
  end

  defp forget(ref),
    do: :ets.select_delete(Tables.batched(), [{{{ref, :_}, :_, :_}, [], [true]}])

  ## The process

  @impl true
  def init(:ok), do: {:ok, check(%{timers: %{}, gaps: %{}})}

  # a timer for every subscription holding tuples
  defp check(state) do
    Process.send_after(self(), :check, @gap_ms)

    :ets.select(Tables.batches(), [
      {{:"$1", :"$2", :"$3", :_, :_, :"$4", :_}, [{:>, :"$2", :"$3"}], [{{:"$1", :"$4"}}]}
    ])
    |> Enum.reduce(state, fn {ref, delay}, state -> arm(state, ref, delay) end)
  end

  @impl true
  def handle_info({:pending, ref}, state) do
    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, _, _, _, _, delay, _}] -> {:noreply, arm(state, ref, delay)}
      [] -> {:noreply, state}
    end
  end

  def handle_info({:full, ref}, state), do: {:noreply, state |> disarm(ref) |> flush(ref)}

  def handle_info({:due, ref}, state),
    do: {:noreply, %{state | timers: Map.delete(state.timers, ref)} |> flush(ref)}

  def handle_info({:closed, ref}, state) do
    Process.send_after(self(), {:sweep, ref}, @sweep_ms)
    {:noreply, %{disarm(state, ref) | gaps: Map.delete(state.gaps, ref)}}
  end

  def handle_info({:sweep, ref}, state) do
    forget(ref)
    {:noreply, state}
  end

  def handle_info(:check, state), do: {:noreply, check(state)}

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def handle_call({:flush, ref}, _from, state) do
    state = disarm(state, ref)

    state =
      case :ets.lookup(Tables.batches(), ref) do
        [{^ref, next, sent, pid, max_batch, delay, _max_queue}] ->
          send_held(state, ref, {sent, next}, pid, max_batch, delay)

        [] ->
          state
      end

    {:reply, :ok, state}
  end

  defp arm(state, ref, delay) do
    if Map.has_key?(state.timers, ref) do
      state
    else
      timer = Process.send_after(self(), {:due, ref}, delay)
      %{state | timers: Map.put(state.timers, ref, timer)}
    end
  end

  defp disarm(state, ref) do
    case Map.pop(state.timers, ref) do
      {nil, _} ->
        state

      {timer, timers} ->
        Process.cancel_timer(timer)
        %{state | timers: timers}
    end
  end

  defp flush(state, ref) do
    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, next, sent, pid, max_batch, delay, max_queue}] ->
        if backed_up?(pid, max(div(max_queue, max_batch), 1)),
          do: arm(state, ref, delay),
          else: send_held(state, ref, {sent, next}, pid, max_batch, delay)

      [] ->
        state
    end
  end

  defp backed_up?(pid, limit) do
    case Process.info(pid, :message_queue_len) do
      {:message_queue_len, queued} -> queued >= limit
      nil -> false
    end
  end

  defp send_held(state, ref, {sent, next}, pid, max_batch, delay) do
    rows =
      :ets.select(Tables.batched(), [
        {{{ref, :"$1"}, :"$2", :"$3"}, [{:>, :"$1", sent}], [{{:"$1", :"$2", :"$3"}}]}
      ])

    {entries, last, state} = take_run(rows, sent, next, state, ref, [])

    entries
    |> Enum.chunk_every(max_batch)
    |> Enum.each(&send(pid, {:blackboard_batch, ref, &1}))

    if last > sent do
      :ets.update_element(Tables.batches(), ref, {3, last})

      :ets.select_delete(Tables.batched(), [
        {{{ref, :"$1"}, :_, :_}, [{:"=<", :"$1", last}], [true]}
      ])
    end

    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, next, _, _, _, _, _}] when next > last -> arm(state, ref, delay)
      _ -> state
    end
  end

  # the held tuples that follow `last` without a gap, oldest first, and
  # the last position taken; a gap (a position taken before `next`, or
  # before a row, and not inserted) older than @gap_ms is passed over
  defp take_run([{position, tuple, at} | rest], last, next, state, ref, acc)
       when position == last + 1 do
    acc = if tuple == :dropped, do: acc, else: [{tuple, at} | acc]
    take_run(rest, position, next, state, ref, acc)
  end

  defp take_run([], last, next, state, ref, acc) when last >= next,
    do: {Enum.reverse(acc), last, %{state | gaps: Map.delete(state.gaps, ref)}}

  defp take_run(rows, last, next, state, ref, acc) do
    gap = last + 1
    now = System.monotonic_time(:millisecond)

    case state.gaps do
      %{^ref => {^gap, seen}} when now - seen >= @gap_ms ->
        take_run(rows, gap, next, %{state | gaps: Map.delete(state.gaps, ref)}, ref, acc)

      %{^ref => {^gap, _seen}} ->
        {Enum.reverse(acc), last, state}

      _ ->
        {Enum.reverse(acc), last, %{state | gaps: Map.put(state.gaps, ref, {gap, now})}}
    end
  end
end
