defmodule ThinkingCap.Blackboard.Core.Store do
  @moduledoc false
  # Tuple records in this node's ETS tables: the tuples this node owns (it
  # wrote them) and replicas of every other node's.
  #
  # A record is {key, tuple, key_bin, expires, stamp}:
  #   key      {arity, first, second, seq, owner_node}: the first two
  #            elements (tag and robot id by convention) index the ordered
  #            table; seq is strictly increasing on the owner, so the tuples
  #            of one tag and robot are walked oldest first.
  #   key_bin  the latest-value key (`out(t, key: k)`) as a binary, or nil.
  #   expires  monotonic milliseconds on *this* node, or :infinity.
  #   stamp    {os_time_us, seq, node} for keyed tuples (last-writer-wins).
  #
  # Two tables hold records:
  #   tuples  every record, ordered by key. Takes happen here only.
  #   fresh   the same record plus its writer's pid, for a local write that
  #           wakes local subscribers: from just before they are sent it
  #           until it is settled, just after the writer yielded to them.
  #
  # Inserting into tuples lands on a cold path of its tree (about 1 us with
  # the benchmark's 1,000 streams), where fresh holds a handful of rows and
  # stays in cache: staging there keeps the insert off the subscribers'
  # latency. Settling copies the record into tuples, claims its latest-value
  # key, then deletes its fresh row, so a record is always in one table or
  # both (until a keyed one loses its key). Readers look in tuples,
  # then in fresh, then in tuples again: a write settled while the first
  # walk was past it, and gone from fresh when fresh was read, was copied
  # before that.
  #
  # No take happens while a record's fresh row exists: a taker that finds
  # the record waits until it is settled (its writer settles it right after
  # yielding to the subscribers it woke, which is when they run). The
  # sweeper relies on that to settle what a killed writer left in fresh
  # without bringing back a tuple that was taken.
  #
  # Between nodes a record travels as {key, tuple, key_bin, stamp, ttl_left}.

  alias ThinkingCap.Blackboard.Core.Tables
  alias ThinkingCap.Blackboard.Template

  @type record :: {tuple(), tuple(), binary() | nil, integer() | :infinity, tuple() | nil}
  @type wire :: {tuple(), tuple(), binary() | nil, tuple() | nil, non_neg_integer() | :infinity}

  @remote_take_timeout :infinity

  def now, do: System.monotonic_time(:millisecond)

  @doc false
  @spec new_record(tuple(), term(), pos_integer() | nil) :: record()
  def new_record(tuple, ukey, ttl) do
    seq = :erlang.unique_integer([:monotonic, :positive])
    key = {tuple_size(tuple), element(tuple, 1), element(tuple, 2), seq, node()}
    expires = if ttl, do: now() + ttl, else: :infinity

    case ukey do
      nil ->
        {key, tuple, nil, expires, nil}

      _ ->
        {key, tuple, :erlang.term_to_binary(ukey), expires,
         {System.os_time(:microsecond), seq, node()}}
    end
  end

  defp element(tuple, pos) when tuple_size(tuple) >= pos, do: elem(tuple, pos - 1)
  defp element(_tuple, _pos), do: nil

  @doc false
  def key_owner({_, _, _, _, owner}), do: owner
  @doc false
  def key_seq({_, _, _, seq, _}), do: seq
  @doc false
  def seq({key, _, _, _, _}), do: key_seq(key)

  # a record-key pattern selecting one owner's records
  defp owner_key(owner), do: {:_, :_, :_, :_, owner}

  ## Writing

  @doc false
  # A local write's first half, before its subscribers are sent it: from
  # here on readers find it.
  @spec stage(record()) :: true
  def stage({key, tuple, key_bin, expires, stamp}),
    do: :ets.insert(Tables.fresh(), {key, tuple, key_bin, expires, stamp, self()})

  @doc false
  # A staged write's second half: copy it into tuples, for a keyed one
  # replace the older tuple with the same key, then drop its fresh row (which
  # until then tells the sweeper that the write is unfinished).
  @spec settle(record()) :: :ok | :stale
  def settle({key, _, _, _, _} = record) do
    :ets.insert(Tables.tuples(), record)
    claimed = claim(record)
    :ets.delete(Tables.fresh(), key)
    claimed
  end

  @doc false
  # Inserts a record in one step (a write nobody has been told of, a
  # replica, a record from a snapshot); for a keyed one, replaces the older
  # tuple with the same key. The new record is inserted before the old one
  # is removed, so a reader sees one or (for an instant) both, never neither.
  @spec insert(record()) :: :ok | :stale
  def insert(record) do
    :ets.insert(Tables.tuples(), record)
    claim(record)
  end

  defp claim({_key, _tuple, nil, _expires, _stamp}), do: :ok

  defp claim({key, _tuple, key_bin, _expires, stamp}) do
    losers = claim_key(key_bin, {key, stamp}, [])
    Enum.each(losers, &:ets.delete(Tables.tuples(), &1))
    if key in losers, do: :stale, else: :ok
  end

  # Lock-free claim of the latest-value index. :ets.take hands the entry
  # there to exactly one writer, which compares it with its candidate, and
  # :ets.insert_new lets exactly one writer install the winner; a writer
  # that finds another's entry installed meanwhile takes and compares that
  # one too. Every entry taken is compared once, so the index ends on the
  # newest record and each writer returns the record keys that lost in its
  # hands (its own among them when it was stale), which it deletes. One
  # that finds its own record installed puts it back.
  # (One take and one insert_new: a compare-and-swap by select_replace
  # costs a match-specification compile, 1.5 us, on every keyed write.)
  defp claim_key(key_bin, {key, stamp} = candidate, losers) do
    keys = Tables.keys()

    case :ets.take(keys, key_bin) do
      [] ->
        if :ets.insert_new(keys, {key_bin, key, stamp}),
          do: losers,
          else: claim_key(key_bin, candidate, losers)

      [{^key_bin, ^key, _stamp}] ->
        claim_key(key_bin, candidate, losers)

      [{^key_bin, old_key, old_stamp}] ->
        if newer?(stamp, old_stamp) or not :ets.member(Tables.tuples(), old_key),
          do: claim_key(key_bin, candidate, [old_key | losers]),
          else: claim_key(key_bin, {old_key, old_stamp}, [key | losers])
    end
  end

  # Same writer node: its sequence decides. Different nodes: wall-clock time,
  # then node name, so that every node picks the same winner.
  defp newer?({_, seq_a, node}, {_, seq_b, node}), do: seq_a > seq_b
  defp newer?({time_a, _, node_a}, {time_b, _, node_b}), do: {time_a, node_a} > {time_b, node_b}

  defp forget_key(nil, _key), do: 0

  defp forget_key(key_bin, key) do
    :ets.select_delete(Tables.keys(), [
      {{key_bin, :"$1", :_}, [{:"=:=", :"$1", {:const, key}}], [true]}
    ])
  end

  @doc false
  # Removes a record (a replica told of a take, a stale replica); true if
  # it was here.
  @spec delete(tuple()) :: boolean()
  def delete(key) do
    case :ets.take(Tables.tuples(), key) do
      [{^key, _tuple, key_bin, _expires, _stamp}] ->
        forget_key(key_bin, key)
        true

      [] ->
        false
    end
  end

  @doc false
  # A replica told of a take: writes travel through the writer node's
  # replicator while takes travel through the owner's server, so the delete
  # may arrive first. It then leaves a tombstone that stops the late insert.
  @spec delete_replica(tuple()) :: :ok
  def delete_replica(key) do
    unless delete(key), do: :ets.insert(Tables.tombs(), {key, now()})
    :ok
  end

  @doc false
  # True (and the tombstone gone) when a delete for `key` came first.
  @spec tombstoned?(tuple()) :: boolean()
  def tombstoned?(key), do: :ets.take(Tables.tombs(), key) != []

  ## Reading
  #
  # Every read looks in tuples, then in fresh, then in tuples again (see
  # above). A template that binds a stream (tag and robot) walks that
  # stream's range with ets:next, where a select would compile its match
  # specification on every call (measured: a warm rdp 1.9 us by select,
  # 1.5 us by walking). The range holds the keys whose arity and first two
  # elements compare equal (==) to the template's; each record is still
  # matched exactly.

  @doc false
  @spec first_match(Template.compiled()) :: {:ok, tuple()} | :none
  def first_match(template) do
    now = now()

    with :none <- find(Tables.tuples(), template, now),
         :none <- find(Tables.fresh(), template, now),
         do: find(Tables.tuples(), template, now)
  end

  defp find(table, %Template{index: {:stream, _, _, _}} = template, now),
    do: stream_find(table, stream_start(template), template, now)

  defp find(table, template, now) do
    case :ets.select(table, match_spec(table, template, now, {:element, 2, :"$_"}), 1) do
      {[tuple], _cont} -> {:ok, tuple}
      :"$end_of_table" -> :none
    end
  end

  defp match_spec(table, template, now, body),
    do:
      Template.record_match_spec(template, now, body, if(table == Tables.fresh(), do: 1, else: 0))

  defp stream_start(%Template{index: {:stream, n, first, second}}), do: {n, first, second, 0, nil}

  defp stream_next(table, key, %Template{index: {:stream, n, first, second}}) do
    case :ets.next(table, key) do
      {^n, f, s, _, _} = next when f == first and s == second -> next
      _end_of_stream -> nil
    end
  end

  defp live_match(table, key, template, now) do
    case :ets.lookup(table, key) do
      [row] when elem(row, 3) > now ->
        tuple = elem(row, 1)
        if Template.matches?(template, tuple), do: {:ok, tuple}, else: :none

      _gone_or_expired ->
        :none
    end
  end

  defp stream_find(table, from, template, now) do
    case stream_next(table, from, template) do
      nil ->
        :none

      key ->
        with :none <- live_match(table, key, template, now),
             do: stream_find(table, key, template, now)
    end
  end

  # up to `left` keys of live matching records after `from`, oldest first,
  # and the last key looked at
  defp stream_keys(_table, from, _template, _now, 0, acc), do: {Enum.reverse(acc), from}

  defp stream_keys(table, from, template, now, left, acc) do
    case stream_next(table, from, template) do
      nil ->
        {Enum.reverse(acc), from}

      key ->
        case live_match(table, key, template, now) do
          {:ok, _} -> stream_keys(table, key, template, now, left - 1, [key | acc])
          :none -> stream_keys(table, key, template, now, left, acc)
        end
    end
  end

  @key_and_tuple {{{:element, 1, :"$_"}, {:element, 2, :"$_"}}}

  @doc false
  @spec all_matches(Template.compiled()) :: [tuple()]
  def all_matches(template) do
    # fresh first, then tuples: a staged write gone from fresh by then was
    # copied before
    now = now()
    fresh = Tables.fresh()

    staged =
      if :ets.first(fresh) == :"$end_of_table",
        do: [],
        else: :ets.select(fresh, match_spec(fresh, template, now, @key_and_tuple))

    body = if staged == [], do: {:element, 2, :"$_"}, else: @key_and_tuple

    stored = :ets.select(Tables.tuples(), match_spec(Tables.tuples(), template, now, body))

    case staged do
      [] ->
        stored

      _ ->
        (staged ++ stored)
        |> Enum.sort()
        |> Enum.dedup_by(&elem(&1, 0))
        |> Enum.map(&elem(&1, 1))
    end
  end

  @doc false
  # How many settled live tuples match `template`, counting up to `limit`
  # (a staged one is told of by its own arrival once settled).
  @spec count_matches(Template.compiled(), pos_integer()) :: non_neg_integer()
  def count_matches(template, limit) do
    table = Tables.tuples()

    case :ets.select(table, match_spec(table, template, now(), true), limit) do
      {found, _continuation} -> length(found)
      :"$end_of_table" -> 0
    end
  end

  @doc false
  @spec all_tuples() :: [tuple()]
  def all_tuples do
    :ets.select(Tables.tuples(), [{{:_, :"$1", :_, :"$2", :_}, [{:>, :"$2", now()}], [:"$1"]}])
  end

  ## Taking

  @batch 16

  @doc false
  # Linda `inp`: the oldest matching tuple this node owns, else the oldest of
  # another node's, taken through its owner so that exactly one taker in the
  # cluster gets it. Matches found in fresh come after those in tuples.
  @spec take_first(Template.compiled()) :: {:ok, tuple()} | :none
  def take_first(template) do
    with :none <- take_stored(template),
         :none <- take_from(batch(Tables.fresh(), template, @batch)),
         do: take_stored(template)
  end

  defp take_stored(template) do
    # The oldest match alone first: it is this node's more often than not,
    # and finding 16 costs 3x finding one. Otherwise batches of 16, this
    # node's taken first, as remote takes cost a round trip.
    tuples = Tables.tuples()

    case batch(tuples, template, 1) do
      {[key], _next} ->
        if key_owner(key) == node(),
          do: take_from({[key], fn -> batch(tuples, template, @batch) end}),
          else: take_from(batch(tuples, template, @batch))

      {[], _next} ->
        take_from(batch(tuples, template, @batch))

      :done ->
        :none
    end
  end

  # The keys of up to `size` live matching records, oldest first, and how
  # to get the next batch; :done when there are no more.
  defp batch(table, %Template{index: {:stream, _, _, _}} = template, size),
    do: stream_batch(table, stream_start(template), template, now(), size)

  defp batch(table, template, size) do
    select_batch(
      :ets.select(table, match_spec(table, template, now(), {:element, 1, :"$_"}), size)
    )
  end

  defp select_batch(:"$end_of_table"), do: :done
  defp select_batch({keys, cont}), do: {keys, fn -> select_batch(:ets.select(cont)) end}

  defp stream_batch(table, from, template, now, size) do
    case stream_keys(table, from, template, now, size, []) do
      {[], _last} -> :done
      {keys, last} -> {keys, fn -> stream_batch(table, last, template, now, @batch) end}
    end
  end

  defp take_from(:done), do: :none

  defp take_from({keys, next_batch}) do
    {local, remote} = Enum.split_with(keys, &(key_owner(&1) == node()))

    case take_any(local ++ remote) do
      {:ok, tuple} -> {:ok, tuple}
      :none -> take_from(next_batch.())
    end
  end

  defp take_any([]), do: :none

  defp take_any([key | rest]) do
    case take_at(key_owner(key), key) do
      {:ok, tuple} -> {:ok, tuple}
      :gone -> take_any(rest)
    end
  end

  defp take_at(owner, key) when owner == node(), do: take_owned(key)

  defp take_at(owner, key) do
    # The owner's atomic ets:take decides who gets the tuple. The call runs
    # in a process erpc spawns on the owner, not in its server, so a crash
    # of that server cannot lose a tuple between take and reply; erpc ends
    # with :noconnection when the owner's node goes away.
    case :erpc.call(owner, __MODULE__, :take_owned, [key], @remote_take_timeout) do
      {:ok, tuple} ->
        delete(key)
        {:ok, tuple}

      :gone ->
        delete(key)
        :gone
    end
  catch
    :error, {:erpc, _reason} ->
      # The owner is unreachable: its tuples are purged on nodedown.
      delete(key)
      :gone
  end

  @doc false
  # Runs on the owner node. The only place where an owned tuple is taken.
  @spec take_owned(tuple()) :: {:ok, tuple()} | :gone
  def take_owned(key) do
    await_settled(key, 0)

    case :ets.take(Tables.tuples(), key) do
      [{^key, tuple, key_bin, expires, _stamp}] ->
        forget_key(key_bin, key)
        ThinkingCap.Blackboard.Core.Server.taken(key)
        if expires > now(), do: {:ok, tuple}, else: :gone

      [] ->
        :gone
    end
  end

  # A staged record is taken only once it is settled: until its fresh row
  # is gone, a take waits (its writer settles it right after the yield that
  # let the taker run; a killed writer's, the sweeper within a second).
  defp await_settled(key, waited) do
    if :ets.member(Tables.fresh(), key) do
      if waited < 10, do: yield_to_writer(), else: Process.sleep(1)
      await_settled(key, waited + 1)
    end
  end

  # A yield lets only processes of the caller's priority or higher run: a
  # high-priority taker yields as a normal one, so that a normal writer
  # waiting to settle gets its turn.
  defp yield_to_writer do
    case Process.flag(:priority, :normal) do
      :normal ->
        :erlang.yield()

      priority ->
        :erlang.yield()
        Process.flag(:priority, priority)
    end
  end

  ## Replication

  @doc false
  @spec to_wire(record()) :: wire()
  def to_wire({key, tuple, key_bin, expires, stamp}) do
    ttl_left = if expires == :infinity, do: :infinity, else: max(expires - now(), 0)
    {key, tuple, key_bin, stamp, ttl_left}
  end

  @doc false
  @spec from_wire(wire()) :: record()
  def from_wire({key, tuple, key_bin, stamp, ttl_left}) do
    expires = if ttl_left == :infinity, do: :infinity, else: now() + ttl_left
    {key, tuple, key_bin, expires, stamp}
  end

  @doc false
  @spec member?(tuple()) :: boolean()
  def member?(key), do: :ets.member(Tables.tuples(), key) or :ets.member(Tables.fresh(), key)

  @doc false
  # Every live record this node owns, as wire records, oldest first.
  @spec owned_snapshot() :: [wire()]
  def owned_snapshot do
    now = now()
    ms = [{{owner_key(node()), :_, :_, :"$1", :_}, [{:>, :"$1", now}], [:"$_"]}]

    staged =
      for {key, tuple, key_bin, expires, stamp, _writer} <- :ets.tab2list(Tables.fresh()),
          expires > now,
          do: {key, tuple, key_bin, expires, stamp}

    (:ets.select(Tables.tuples(), ms) ++ staged)
    |> Enum.uniq_by(&elem(&1, 0))
    |> Enum.map(&to_wire/1)
    |> Enum.sort_by(fn {key, _, _, _, _} -> key_seq(key) end)
  end

  @doc false
  # The snapshot's high-water mark: every record with a lower seq that is
  # not in a snapshot taken after it had been taken or had expired.
  @spec high_water() :: pos_integer()
  def high_water, do: :erlang.unique_integer([:monotonic, :positive])

  @doc false
  # Makes this node's replicas of `owner`'s tuples equal to its snapshot,
  # except for records newer than the snapshot (`high` and above), which
  # writers may have sent ahead of it. Returns the records that were not
  # here before, oldest first.
  @spec sync(node(), pos_integer(), [wire()]) :: [record()]
  def sync(owner, high, snapshot) do
    have = MapSet.new(owned_keys(owner))
    incoming = MapSet.new(snapshot, &elem(&1, 0))

    for key <- have, key_seq(key) < high, not MapSet.member?(incoming, key), do: delete(key)

    for wire <- snapshot,
        not MapSet.member?(have, elem(wire, 0)),
        not tombstoned?(elem(wire, 0)),
        reduce: [] do
      acc ->
        record = from_wire(wire)
        insert(record)
        [record | acc]
    end
    |> Enum.reverse()
  end

  defp owned_keys(owner) do
    :ets.select(Tables.tuples(), [
      {{owner_key(owner), :_, :_, :_, :_}, [], [{:element, 1, :"$_"}]}
    ])
  end

  @doc false
  # Forgets every tuple owned by `owner` (its node went away).
  @spec purge(node()) :: non_neg_integer()
  def purge(owner) do
    count =
      :ets.select_delete(Tables.tuples(), [{{owner_key(owner), :_, :_, :_, :_}, [], [true]}])

    :ets.select_delete(Tables.keys(), [{{:_, owner_key(owner), :_}, [], [true]}])
    count
  end

  @doc false
  # Deletes expired records and old tombstones, and settles what killed
  # writers left staged; returns how many records expired.
  @spec sweep() :: non_neg_integer()
  def sweep do
    now = now()
    :ets.select_delete(Tables.tombs(), [{{:_, :"$1"}, [{:<, :"$1", now - 60_000}], [true]}])
    ms = [{{:"$1", :_, :"$2", :"$3", :_}, [{:"=<", :"$3", now}], [{{:"$1", :"$2"}}]}]

    expired = :ets.select(Tables.tuples(), ms)

    for {key, key_bin} <- expired do
      :ets.delete(Tables.tuples(), key)
      forget_key(key_bin, key)
    end

    settle_abandoned()
    length(expired)
  end

  # A staged write whose writer died before settling it. A dead writer
  # copies nothing more, and no take happens while a fresh row exists: so
  # a record in tuples now was copied (its key is claimed again, in case
  # the writer died before it did, and its fresh row goes), and one missing
  # from tuples was never copied, and is copied here (or lost its key to a
  # newer write, and loses it again as soon as it is copied). (Taking
  # the fresh row first and looking in tuples after would let a taker take
  # the copy in between, and the record be copied again.)
  defp settle_abandoned do
    fresh = Tables.fresh()
    abandoned = :ets.select(fresh, [{{:"$1", :_, :_, :_, :_, :"$2"}, [], [{{:"$1", :"$2"}}]}])

    for {key, writer} <- abandoned, not Process.alive?(writer) do
      if :ets.member(Tables.tuples(), key) do
        # copied; its key may not have been claimed (claiming twice is
        # harmless: the index keeps the newest either way)
        with [{^key, tuple, key_bin, expires, stamp, _writer}] <- :ets.lookup(fresh, key),
             do: claim({key, tuple, key_bin, expires, stamp})

        :ets.delete(fresh, key)
      else
        with [{^key, tuple, key_bin, expires, stamp, _writer}] <- :ets.take(fresh, key),
             do: insert({key, tuple, key_bin, expires, stamp})
      end
    end

    :ok
  end
end
