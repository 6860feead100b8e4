defmodule ThinkingCap.Blackboard.Core.Waiters do
  @moduledoc false
  # Blocked rd/take requests. A waiter is a row in an ETS table that the
  # blocked process writes itself, so no request is lost when the server
  # restarts. The server wakes waiters with {:tc_bb_wake, ref, tuple}: a
  # reader is handed the tuple that woke it (reading consumes nothing, and
  # every blocked reader must see it even if a taker is faster); a taker is
  # woken with nil and makes the take itself, so a tuple is never held in
  # flight by the server. Rows are {{index, wseq}, pid, ref, kind, template, woken?}:
  # wseq orders waiters by arrival, the woken flag says a wake-up is on its
  # way so later arrivals go to the next waiter.

  alias ThinkingCap.Blackboard.Core.{Server, Store, Tables}
  alias ThinkingCap.Blackboard.Template

  @type kind :: :rd | :take

  @count Tables.counter(:waiters)

  @doc false
  # Runs `attempt` until it yields a tuple or `timeout` ms pass.
  @spec await(kind(), Template.compiled(), timeout(), (() -> {:ok, tuple()} | :none)) ::
          {:ok, tuple()} | {:error, :timeout}
  def await(kind, template, timeout, attempt) do
    case attempt.() do
      {:ok, tuple} ->
        {:ok, tuple}

      :none when timeout == 0 ->
        {:error, :timeout}

      :none ->
        ref = make_ref()
        wkey = {template.index, :erlang.unique_integer([:monotonic, :positive])}
        # counted before the row exists and uncounted after it is gone: the
        # count is never below the rows (see any?/1)
        :counters.add(Tables.counters(), @count, 1)
        :ets.insert(Tables.waiters(), {wkey, self(), ref, kind, template, false})
        Server.notify({:kick, wkey})

        deadline =
          if timeout == :infinity,
            do: :infinity,
            else: System.monotonic_time(:millisecond) + timeout

        wait(wkey, ref, deadline, attempt)
    end
  end

  defp wait(wkey, ref, deadline, attempt) do
    receive do
      {:tc_bb_wake, ^ref, tuple} when tuple != nil ->
        forget(wkey)
        flush(ref)
        {:ok, tuple}

      {:tc_bb_wake, ^ref, nil} ->
        case attempt.() do
          {:ok, tuple} ->
            forget(wkey)
            flush(ref)
            {:ok, tuple}

          :none ->
            # Somebody else got it: wait again.
            :ets.update_element(Tables.waiters(), wkey, {6, false})
            Server.notify({:kick, wkey})
            wait(wkey, ref, deadline, attempt)
        end
    after
      remaining(deadline) ->
        case :ets.take(Tables.waiters(), wkey) do
          # A wake-up was on its way: let the next waiter have that tuple.
          [{_, _, _, _, _, true}] -> Server.notify(:rescan)
          _ -> :ok
        end

        :counters.sub(Tables.counters(), @count, 1)

        flush(ref)
        {:error, :timeout}
    end
  end

  # only the waiter itself removes its row while it lives
  defp forget(wkey) do
    :ets.delete(Tables.waiters(), wkey)
    :counters.sub(Tables.counters(), @count, 1)
  end

  defp remaining(:infinity), do: :infinity
  defp remaining(deadline), do: max(deadline - System.monotonic_time(:millisecond), 0)

  defp flush(ref) do
    receive do
      {:tc_bb_wake, ^ref, _} -> flush(ref)
    after
      0 -> :ok
    end
  end

  ## Server side

  @doc false
  # Whether any process may be blocked. The count spares writers the table
  # probe when nobody waits; it may stay above the rows when a waiter is
  # killed between the two, which only costs the probe. (ets:info(T, :size)
  # sums per-scheduler counters: :ets.first/1 is cheaper.)
  @spec any?(:counters.counters_ref()) :: boolean()
  def any?(counters \\ Tables.counters()) do
    :counters.get(counters, @count) > 0 and :ets.first(Tables.waiters()) != :"$end_of_table"
  end

  @doc false
  # On the arrival of `tuple`: hand it to every matching rd waiter and wake
  # the longest-waiting matching take waiter that is not already woken,
  # unless older takers of its template are already on their way to every
  # tuple it could take (see `spare_tuple?/1`).
  @spec arrived(tuple()) :: :ok
  def arrived(tuple) do
    groups = Template.bound_indexes(tuple) ++ [{:any, tuple_size(tuple)}, :spec]

    groups
    |> Enum.flat_map(&sleeping_in/1)
    |> Enum.filter(fn {_wkey, _pid, _ref, _kind, template, _} ->
      Template.matches?(template, tuple)
    end)
    |> Enum.sort_by(fn {{_, wseq}, _, _, _, _, _} -> wseq end)
    |> wake_for_arrival(tuple, false)
  end

  defp sleeping_in(index) do
    :ets.select(Tables.waiters(), [
      {{{:"$1", :_}, :_, :_, :_, :_, false}, [{:"=:=", :"$1", {:const, index}}], [:"$_"]}
    ])
  end

  defp wake_for_arrival([], _tuple, _taker_woken?), do: :ok

  defp wake_for_arrival([{_, _, _, :rd, _, _} = waiter | rest], tuple, taker_woken?) do
    wake(waiter, tuple)
    wake_for_arrival(rest, tuple, taker_woken?)
  end

  defp wake_for_arrival([{_, _, _, :take, _, _} = waiter | rest], tuple, false) do
    # a taker that would race older ones for the same tuples is not woken,
    # nor any after it: the tuple is theirs
    woken_or_left = not spare_tuple?(waiter) or wake(waiter, tuple)
    wake_for_arrival(rest, tuple, woken_or_left)
  end

  defp wake_for_arrival([_taker | rest], tuple, true), do: wake_for_arrival(rest, tuple, true)

  # Whether a taker woken now would find a tuple that no older taker of its
  # template, woken before it, is on its way to: none is, or more tuples
  # match than there are such takers. Blocked takers of one template are
  # served in arrival order: an arrival (or a kick, served as one) that
  # comes while an older taker has been woken for the only tuple does not
  # wake the next taker to race it. If the older taker finds nothing (a
  # takep got there first), it waits again and its kick looks once more.
  defp spare_tuple?({{index, wseq}, _pid, _ref, :take, template, _woken}) do
    # (the same template by its source: a match specification compiled
    # twice is two references)
    ahead =
      Tables.waiters()
      |> :ets.select([
        {{{:"$1", :"$2"}, :_, :_, :take, :"$3", true},
         [{:andalso, {:"=:=", :"$1", {:const, index}}, {:<, :"$2", wseq}}], [:"$3"]}
      ])
      |> Enum.count(&(&1.source == template.source))

    ahead == 0 or Store.count_matches(template, ahead + 1) > ahead
  end

  @doc false
  # A new or re-armed waiter: if a matching tuple is there already (`find`
  # returns one), it is served as an arrival: the kick may reach the server
  # after a tuple that older waiters are waiting for, which then go first.
  @spec kicked(tuple(), (Template.compiled() -> {:ok, tuple()} | :none)) :: pid() | nil
  def kicked(wkey, find) do
    case :ets.lookup(Tables.waiters(), wkey) do
      [{^wkey, pid, _, _, template, false}] ->
        with {:ok, tuple} <- find.(template), do: arrived(tuple)
        pid

      _ ->
        nil
    end
  end

  @doc false
  # Wakes every sleeping waiter for which a matching tuple exists, in order
  # of arrival (after a restart, a timed-out or dead woken waiter).
  @spec rescan((Template.compiled() -> {:ok, tuple()} | :none)) :: :ok
  def rescan(find) do
    Tables.waiters()
    |> :ets.select([{{:_, :_, :_, :_, :_, false}, [], [:"$_"]}])
    |> Enum.sort_by(fn {{_, wseq}, _, _, _, _, _} -> wseq end)
    |> Enum.each(fn {_, _, _, _, template, _} = waiter ->
      with {:ok, tuple} <- find.(template), do: wake(waiter, tuple)
    end)
  end

  @doc false
  # Marks every waiter asleep (a restarted server cannot know which wake-ups
  # reached their waiters; a spare wake-up only costs an attempt).
  @spec reset() :: non_neg_integer()
  def reset do
    :ets.select_replace(Tables.waiters(), [
      {{:"$1", :"$2", :"$3", :"$4", :"$5", :_}, [],
       [{{:"$1", :"$2", :"$3", :"$4", :"$5", false}}]}
    ])
  end

  @doc false
  @spec pids() :: [pid()]
  def pids,
    do:
      Tables.waiters() |> :ets.select([{{:_, :"$1", :_, :_, :_, :_}, [], [:"$1"]}]) |> Enum.uniq()

  @doc false
  # Removes a dead process's waiters; true when one of them had been woken.
  @spec drop_pid(pid()) :: boolean()
  def drop_pid(pid) do
    woken = :ets.select(Tables.waiters(), [{{:_, pid, :_, :_, :_, :"$1"}, [], [:"$1"]}])
    gone = :ets.select_delete(Tables.waiters(), [{{:_, pid, :_, :_, :_, :_}, [], [true]}])
    :counters.sub(Tables.counters(), @count, gone)
    Enum.any?(woken)
  end

  @doc false
  @spec list() :: [map()]
  def list do
    for {{_, wseq}, pid, _ref, kind, template, woken} <- :ets.tab2list(Tables.waiters()) do
      %{seq: wseq, pid: pid, kind: kind, template: template.source, woken: woken}
    end
  end

  # The woken flag is set first; if the row is gone (the waiter timed out),
  # nobody is woken and the caller moves on to the next waiter.
  defp wake({wkey, pid, ref, kind, _template, _woken}, tuple) do
    if :ets.update_element(Tables.waiters(), wkey, {6, true}) do
      send(pid, {:tc_bb_wake, ref, if(kind == :rd, do: tuple)})
      true
    else
      false
    end
  end
end
