defmodule ThinkingCap.Blackboard.Core.Batches do
  @moduledoc false
  # Batched subscriptions (`subscribe(t, batch: true)`): their tuples are
  # held in a table, and the subscriber is told `{:blackboard_held, ref}`
  # when `max_batch` are held or `max_delay_ms` after the first; it then
  # takes them all from the table itself (`take/1`), so that it is woken
  # once a list and not once a tuple, and a tuple is copied once on its
  # way (into the table, out of it), as a message is. This process, one
  # per node, only keeps the timers and sends the notices.
  #
  # A writer (`hold/2`) takes the subscription's next position (one
  # update_counter on its row of `Tables.batches/0`, which reads the
  # position taken last in the same step) and inserts the tuple there in
  # `Tables.batched/0`, with the monotonic time. Positions are dense, and a
  # writer inserts before it takes its next: so `take/1` takes only the
  # positions that follow the last one taken without a gap, in order,
  # and the tuples of one writer come in the order written, whichever
  # tuples of other writers they race with (a position taken but not yet
  # inserted shows a gap, and the rest waits for the next notice); each
  # position is taken out of the table by its key, one at a time.
  # Only the subscriber takes, so takes never race each other.
  #
  # The writer that holds the first tuple after the last take tells this
  # process (a timer of `max_delay_ms`), and the one that holds the
  # `max_batch`th too (a notice at once). One notice at a time is
  # outstanding (the row's flag, cleared by `take/1`). With `max_queue`
  # held, a writer marks its position dropped instead (the subscription's
  # policy applies).
  #
  # A writer killed between taking a position and inserting leaves a gap
  # that never fills (and may not have told this process): every
  # `@gap_ms` it arms a timer for every subscription holding tuples, and
  # `take/1` passes over a gap still there `@gap_ms` after it first saw
  # it. The tables belong to `Tables`: a restart of this process loses
  # nothing held.
  #
  # Row: {ref, next, taken, pid, max_batch, max_delay_ms, max_queue,
  #       notified (0 | 1), gap (nil | {position, first seen, ms})}

  use GenServer

  alias ThinkingCap.Blackboard.Core.Tables

  @gap_ms 1_000
  # tuples a writer inserted after the subscription was closed
  @sweep_ms 1_000

  @doc false
  def start_link(_opts), do: GenServer.start_link(__MODULE__, :ok, name: __MODULE__)

  @doc false
  # A batched subscription's row; before its subscription row is inserted.
  @spec open(reference(), pid(), {pos_integer(), pos_integer(), term()}, pos_integer()) :: true
  def open(ref, pid, {max_batch, max_delay_ms, _hold}, max_queue),
    do:
      :ets.insert(
        Tables.batches(),
        {ref, 0, 0, pid, max_batch, max_delay_ms, max_queue, 0, nil}
      )

  @doc false
  # Forgets a batched subscription and the tuples held for it.
  @spec close(reference()) :: :ok
  def close(ref) do
    :ets.delete(Tables.batches(), ref)
    forget(ref)
    notify({:closed, ref})
  end

  @doc false
  # Holds `tuple` (or what the subscription's `hold:` made of it) for the
  # batched subscription `ref`: :ok, or :full when `max_queue` tuples are
  # held already (it is not).
  @spec hold(reference(), term()) :: :ok | :full
  def hold(ref, tuple) do
    [position, taken, max_batch, max_queue] =
      :ets.update_counter(Tables.batches(), ref, [{2, 1}, {3, 0}, {5, 0}, {7, 0}])

    held = position - taken

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
  # In the subscriber: the tuples held for its subscription `ref` that
  # follow the last taken without a gap, oldest first, `[{tuple, at}]`;
  # [] when none (or `ref` is not a batched subscription of the caller).
  @spec take(reference()) :: [{term(), integer()}]
  def take(ref) do
    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, next, taken, pid, _, _, _, _, gap}] when pid == self() ->
        {entries, last, gap} = take_run(ref, taken + 1, next, gap, [])
        :ets.update_element(Tables.batches(), ref, [{3, last}, {8, 0}, {9, gap}])

        # more taken meanwhile, or a gap: a timer for them
        if :ets.lookup_element(Tables.batches(), ref, 2) > last, do: notify({:pending, ref})
        entries

      _other ->
        []
    end
  rescue
    # closed meanwhile
    ArgumentError -> []
  end

  # The held tuples from `position` to `next` (the positions taken when
  # the take began) that follow each other without a gap, oldest first,
  # each taken out of the table (`:ets.take/2`: one key, where a select
  # and a select_delete went through the table); the last position taken,
  # and the gap left (a position taken and not inserted), passed over
  # @gap_ms after it was first seen
  defp take_run(_ref, position, next, _gap, acc) when position > next,
    do: {Enum.reverse(acc), position - 1, nil}

  defp take_run(ref, position, next, gap, acc) do
    case :ets.take(Tables.batched(), {ref, position}) do
      [{_, :dropped, _}] ->
        take_run(ref, position + 1, next, gap, acc)

      [{_, tuple, at}] ->
        take_run(ref, position + 1, next, gap, [{tuple, at} | acc])

      [] ->
        now = System.monotonic_time(:millisecond)

        case gap do
          {^position, seen} when now - seen >= @gap_ms ->
            take_run(ref, position + 1, next, nil, acc)

          {^position, _seen} ->
            {Enum.reverse(acc), position - 1, gap}

          _ ->
            {Enum.reverse(acc), position - 1, {position, now}}
        end
    end
  end

  defp notify(message) do
    case Process.whereis(__MODULE__) do
      nil -> :ok
      pid -> send(pid, message)
    end

    :ok
  end

  defp forget(ref),
    do: :ets.select_delete(Tables.batched(), [{{{ref, :_}, :_, :_}, [], [true]}])

  ## The process: timers and notices

  @impl true
  def init(:ok), do: {:ok, check(%{timers: %{}})}

  # a timer for every subscription holding tuples
  defp check(state) do
    Process.send_after(self(), :check, @gap_ms)

    :ets.select(Tables.batches(), [
      {{:"$1", :"$2", :"$3", :_, :_, :"$4", :_, :_, :_}, [{:>, :"$2", :"$3"}], [{{:"$1", :"$4"}}]}
    ])
    |> Enum.reduce(state, fn {ref, delay}, state -> arm(state, ref, delay) end)
  end

  @impl true
  def handle_info({:pending, ref}, state) do
    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, _, _, _, _, delay, _, _, _}] -> {:noreply, arm(state, ref, delay)}
      [] -> {:noreply, state}
    end
  end

  def handle_info({:full, ref}, state) do
    tell(ref)
    {:noreply, disarm(state, ref)}
  end

  def handle_info({:due, ref}, state) do
    tell(ref)
    {:noreply, %{state | timers: Map.delete(state.timers, ref)}}
  end

  def handle_info({:closed, ref}, state) do
    Process.send_after(self(), {:sweep, ref}, @sweep_ms)
    {:noreply, disarm(state, ref)}
  end

  def handle_info({:sweep, ref}, state) do
    forget(ref)
    {:noreply, state}
  end

  def handle_info(:check, state), do: {:noreply, check(state)}

  def handle_info(_other, state), do: {:noreply, state}

  # tells the subscriber that tuples are held, unless it was told and has
  # not taken them yet
  defp tell(ref) do
    case :ets.lookup(Tables.batches(), ref) do
      [{^ref, next, taken, pid, _, _, _, 0, _}] when next > taken ->
        :ets.update_element(Tables.batches(), ref, {8, 1})
        send(pid, {:blackboard_held, ref})

      _told_or_empty_or_closed ->
        :ok
    end
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
end
