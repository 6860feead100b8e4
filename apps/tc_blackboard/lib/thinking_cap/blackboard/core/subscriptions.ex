defmodule ThinkingCap.Blackboard.Core.Subscriptions do
  @moduledoc false
  # This node's subscriptions, indexed by template index, and delivery of a
  # tuple to the local subscribers it matches. Delivery runs in the writer
  # (local outs) or in the node's server (replicated outs) and never blocks:
  # a subscriber whose mailbox holds `max_queue` messages or more is not
  # sent the tuple (policy :drop, counted) or is unsubscribed and told
  # (policy :disconnect). A writer finds the recipients (`recipients/1`),
  # sends (`send_to/2`) and, once it let them run, reads the queues that
  # were due a read (`check_queues/1`); the server does the three at once
  # (`deliver/1`). A batched subscription's tuples are not sent but held
  # (Batches), and sent to it in lists.

  alias ThinkingCap.Blackboard.Core.{Batches, Server, Tables}
  alias ThinkingCap.Blackboard.Template

  @type policy :: :drop | :disconnect

  @type batch :: nil | {pos_integer(), pos_integer(), {module(), atom()} | nil}

  @spec subscribe(Template.compiled(), pid(), pos_integer(), policy(), batch()) :: reference()
  def subscribe(template, pid, max_queue, on_overflow, batch \\ nil) do
    ref = make_ref()
    :ets.insert(Tables.sub_refs(), {ref, template.index, pid, 0, template.source})
    # its positions before its row: a writer that finds the row can hold tuples
    if batch, do: Batches.open(ref, pid, batch, max_queue)

    row =
      {template.index, ref, pid, Template.residual_matcher(template), max_queue, on_overflow,
       Tables.send_slot(ref), batch}

    :ets.insert(Tables.subs(), row)

    Tables.count_subscription(template.index, 1)
    Server.notify({:monitor, pid})
    ref
  end

  @spec unsubscribe(reference()) :: boolean()
  def unsubscribe(ref) do
    case :ets.take(Tables.sub_refs(), ref) do
      [{^ref, index, _pid, _dropped, _source}] ->
        for {_, ^ref, _, _, _, _, _, batch} = sub <- :ets.lookup(Tables.subs(), index) do
          :ets.delete_object(Tables.subs(), sub)
          if batch, do: Batches.close(ref)
        end

        Tables.count_subscription(index, -1)
        true

      [] ->
        false
    end
  end

  @doc false
  # Removes every subscription of a dead process.
  @spec drop_pid(pid()) :: non_neg_integer()
  def drop_pid(pid) do
    refs = :ets.select(Tables.sub_refs(), [{{:"$1", :_, pid, :_, :_}, [], [:"$1"]}])
    Enum.each(refs, &unsubscribe/1)
    length(refs)
  end

  @spec pids() :: [pid()]
  def pids do
    Tables.sub_refs() |> :ets.select([{{:_, :_, :"$1", :_, :_}, [], [:"$1"]}]) |> Enum.uniq()
  end

  @doc false
  @spec list() :: [map()]
  def list do
    for {_index, ref, pid, _matcher, max_queue, on_overflow, _sent, batch} <-
          :ets.tab2list(Tables.subs()),
        [{^ref, _, _, dropped, source}] <- [:ets.lookup(Tables.sub_refs(), ref)] do
      %{
        ref: ref,
        pid: pid,
        template: source,
        max_queue: max_queue,
        on_overflow: on_overflow,
        dropped: dropped,
        batch:
          case batch do
            nil ->
              false

            {max_batch, max_delay_ms, hold} ->
              %{max_batch: max_batch, max_delay_ms: max_delay_ms, hold: hold}
          end
      }
    end
  end

  @doc false
  @spec dropped(reference()) :: non_neg_integer() | nil
  def dropped(ref) do
    case :ets.lookup(Tables.sub_refs(), ref) do
      [{^ref, _, _, dropped, _source}] -> dropped
      [] -> nil
    end
  end

  @doc false
  # Sends `tuple` to the local subscribers it matches.
  @spec deliver(tuple()) :: :ok
  def deliver(tuple),
    do: tuple |> recipients() |> send_to(tuple) |> check_queues()

  @doc false
  # The local subscriptions `tuple` matches: those of its stream, then, as
  # the index flags say there may be some, those of its tag, of its arity
  # and with match specifications.
  @spec recipients(tuple()) :: [tuple()]
  def recipients(tuple) when tuple_size(tuple) >= 2 do
    n = tuple_size(tuple)
    first = elem(tuple, 0)
    subs = Tables.subs()
    found = matching(:ets.lookup(subs, {:stream, n, first, elem(tuple, 1)}), tuple)

    found =
      if Tables.tag_indexed?(n, first),
        do: matching(:ets.lookup(subs, {:tag, n, first}), tuple) ++ found,
        else: found

    wide(tuple, subs, found)
  end

  def recipients({first} = tuple) do
    subs = Tables.subs()

    found =
      if Tables.tag_indexed?(1, first),
        do: matching(:ets.lookup(subs, {:tag, 1, first}), tuple),
        else: []

    wide(tuple, subs, found)
  end

  def recipients({} = tuple), do: wide(tuple, Tables.subs(), [])

  # subscriptions that may match any tuple
  defp wide(tuple, subs, found) do
    case Tables.wide_indexed() do
      {false, false} ->
        found

      {any?, spec?} ->
        found =
          if any?,
            do: matching(:ets.lookup(subs, {:any, tuple_size(tuple)}), tuple) ++ found,
            else: found

        if spec?, do: matching(:ets.lookup(subs, :spec), tuple) ++ found, else: found
    end
  end

  defp matching([], _tuple), do: []
  defp matching([{_, _, _, {:positions, _, []}, _, _, _, _}] = rows, _tuple), do: rows
  defp matching(rows, tuple), do: Enum.filter(rows, &Template.matches?(elem(&1, 3), tuple))

  @doc false
  # Sends `tuple` to `recipients/1`'s subscriptions. Returns those whose
  # queue is due a read, for `check_queues/1` once the writer has yielded
  # to them.
  @spec send_to([tuple()], tuple()) :: [tuple()]
  def send_to(recipients, tuple), do: send_to(recipients, tuple, [])

  defp send_to([], _tuple, due), do: due

  defp send_to(
         [{_index, ref, pid, _matcher, _max_queue, policy, _slot, {_, _, hold}} | rest],
         tuple,
         due
       ) do
    # held, to be sent in a list: nothing to read about its queue here
    if Batches.hold(ref, held(hold, tuple)) == :full, do: overflow(policy, ref, pid)
    send_to(rest, tuple, due)
  end

  defp send_to(
         [{_index, ref, pid, _matcher, max_queue, policy, slot, nil} = sub | rest],
         tuple,
         due
       ) do
    case send_bounded(ref, pid, max_queue, policy, slot, tuple) do
      :due -> send_to(rest, tuple, [sub | due])
      :sent -> send_to(rest, tuple, due)
    end
  end

  # what a batched subscription holds of a tuple: the tuple, or what its
  # `hold:` function makes of it (the tuple if that raises)
  defp held(nil, tuple), do: tuple

  defp held({m, f}, tuple) do
    apply(m, f, [tuple])
  catch
    _kind, _reason -> tuple
  end

  # Reading another process's queue length costs about a microsecond (the
  # reader absorbs the signals in flight), so the queue is read every
  # max_queue/64 sends, after the send and after the writer let the
  # subscribers run; once a read found it full, it is read before every
  # send, until a read finds room again. The bound holds to within 1/64 of
  # max_queue (and one) per writer sending at that moment, exactly below
  # 128, where every send reads first.
  #
  # The count and the "found full" flag share one word of
  # `Tables.send_counts/0` (count * 2 + flag), so that a send costs one
  # add_get. Two subscriptions whose refs hash to one slot share the word:
  # each is read early now and then, and a read that finds room for one
  # clears the flag of the other, whose next read is then up to
  # max_queue/64 sends away (as for any subscription not yet found full).
  defp send_bounded(ref, pid, max_queue, policy, slot, tuple) do
    counts = Tables.send_counts()
    word = :atomics.add_get(counts, slot, 2)
    every = max(div(max_queue, 64), 1)

    cond do
      Bitwise.band(word, 1) == 1 or every == 1 ->
        if room?(pid, max_queue, counts, slot),
          do: send(pid, {:blackboard, ref, tuple}),
          else: overflow(policy, ref, pid)

        :sent

      rem(Bitwise.bsr(word, 1), every) == 0 ->
        send(pid, {:blackboard, ref, tuple})
        :due

      true ->
        send(pid, {:blackboard, ref, tuple})
        :sent
    end
  end

  @doc false
  # Whether sending `tuple` to `recipients/1`'s subscriptions wakes one
  # (a batched subscription's tuples are held instead).
  @spec wakes?([tuple()]) :: boolean()
  def wakes?(recipients), do: Enum.any?(recipients, &(elem(&1, 7) == nil))

  @doc false
  # Reads the queues `send_to/2` said were due, and marks those found full.
  @spec check_queues([tuple()]) :: :ok
  def check_queues([]), do: :ok

  def check_queues([{_index, ref, pid, _matcher, max_queue, policy, slot, _batch} | rest]) do
    unless room?(pid, max_queue, Tables.send_counts(), slot), do: full(policy, ref, pid)
    check_queues(rest)
  end

  # a dead subscriber has room: nothing is sent to it anyway
  defp room?(pid, max_queue, counts, slot) do
    case Process.info(pid, :message_queue_len) do
      {:message_queue_len, queued} when queued >= max_queue ->
        flag_full(counts, slot, 1)
        false

      _room_or_dead ->
        flag_full(counts, slot, 0)
        true
    end
  end

  # found full after a send: later sends read first, and drop (counted as
  # they are) or disconnect
  defp full(:drop, _ref, _pid), do: :ok
  defp full(:disconnect, ref, pid), do: overflow(:disconnect, ref, pid)

  defp flag_full(counts, slot, flag) do
    word = :atomics.get(counts, slot)

    if Bitwise.band(word, 1) != flag and
         :atomics.compare_exchange(counts, slot, word, Bitwise.bxor(word, 1)) != :ok,
       do: flag_full(counts, slot, flag)
  end

  # a tuple not delivered (its subscriber's queue, or the tuples held for
  # it, full): counted, or the subscription ended and its subscriber told
  defp overflow(:drop, ref, _pid) do
    :ets.update_counter(Tables.sub_refs(), ref, {4, 1})
  rescue
    # unsubscribed meanwhile
    ArgumentError -> :ok
  end

  defp overflow(:disconnect, ref, pid) do
    if unsubscribe(ref), do: send(pid, {:blackboard_overflow, ref})
  end
end
