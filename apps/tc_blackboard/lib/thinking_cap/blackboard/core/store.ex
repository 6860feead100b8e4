defmodule ThinkingCap.Blackboard.Core.Store do
  @moduledoc false
  # Tuple records in this node's ETS tables: the tuples this node owns (it
  # wrote them) and replicas of every other node's.
  #
  # A record is {key, tuple, key_bin, expires, stamp}:
  #   key      {arity, first, second, seq, owner_node}, the tuple's identity
  #            on every node: seq is strictly increasing on the owner, and
  #            the first two elements are tag and robot id by convention.
  #   key_bin  the latest-value key (`out(t, key: k)`) as a binary, or nil.
  #   expires  monotonic milliseconds on *this* node, or :infinity.
  #   stamp    {os_time_us, seq, node} for keyed tuples (last-writer-wins).
  #
  # Three tables hold them:
  #   tuples  {{owner, seq}, tuple, key_bin, expires, stamp}: the records,
  #           ordered by owner then seq, so that this node's writes append
  #           at one end of the tree, on a path that stays in cache. The
  #           only place a take happens (ets:take of the row).
  #   index   {key}: every record's identity, ordered by stream and then
  #           seq, which rd and take walk (a stream, or a tag) oldest first.
  #   fresh   {key}: this node's writes not yet in the index.
  #
  # A local write is staged (fresh, then tuples) before its subscribers
  # are sent it, and settled (index, then out of fresh) after: readers look
  # in the index and then in fresh, so a write is found from the moment it
  # is staged. Inserting into the stream-ordered index lands on a cold path
  # of its tree (about 1 us with the benchmark's 1,000 streams); settling
  # after the send, once the writer has yielded to the subscribers it woke,
  # takes that off their latency. An index entry whose record is gone is
  # skipped by readers and removed by whoever removed the record (or by the
  # settler, which checks for the record after indexing it).
  #
  # Between nodes a record travels as {key, tuple, key_bin, stamp, ttl_left}.

  alias ThinkingCap.Blackboard.Core.Tables
  alias ThinkingCap.Blackboard.Template

  @type record :: {tuple(), tuple(), binary() | nil, integer() | :infinity, tuple() | nil}
  @type wire :: {tuple(), tuple(), binary() | nil, tuple() | nil, non_neg_integer() | :infinity}

  @remote_take_timeout :infinity
  @batch 16

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

  @doc false
  # The tuples table's key of the record whose identity is `key`.
  @spec row_key(tuple()) :: {node(), pos_integer()}
  def row_key({_, _, _, seq, owner}), do: {owner, seq}

  defp identity({owner, seq}, tuple),
    do: {tuple_size(tuple), element(tuple, 1), element(tuple, 2), seq, owner}

  defp to_row({key, tuple, key_bin, expires, stamp}),
    do: {row_key(key), tuple, key_bin, expires, stamp}

  defp to_record({row_key, tuple, key_bin, expires, stamp}),
    do: {identity(row_key, tuple), tuple, key_bin, expires, stamp}

  # an index-key pattern selecting one owner's records
  defp owner_key(owner), do: {:_, :_, :_, :_, owner}

  ## Writing

  @doc false
  # A local write's first half, before its subscribers are sent it: from
  # here on readers find it (through fresh).
  @spec stage(record()) :: :ok
  def stage({key, _, _, _, _} = record) do
    :ets.insert(Tables.fresh(), {key})
    :ets.insert(Tables.tuples(), to_row(record))
    :ok
  end

  @doc false
  # A staged write's second half: index it, leave fresh, and for a keyed
  # one replace the older tuple with the same key. Safe to run twice (the
  # sweeper settles what a killed writer left staged).
  @spec settle(record()) :: :ok | :stale
  def settle({key, _, _, _, _} = record) do
    index(key)
    :ets.delete(Tables.fresh(), key)
    claim(record)
  end

  @doc false
  # Stores a record in one step: a local write nobody has been told of, a
  # replica, a record from a snapshot. The index entry goes in first: until
  # the row follows, readers skip it, and once the row is there a taker
  # removes both (so no check for a removed row is needed, as in settle/1).
  @spec insert(record()) :: :ok | :stale
  def insert({key, _, _, _, _} = record) do
    :ets.insert(Tables.index(), {key})
    :ets.insert(Tables.tuples(), to_row(record))
    claim(record)
  end

  # Indexes a stored record; if it was removed meanwhile, by a taker that
  # found it through fresh before the entry existed, removes the entry again.
  defp index(key) do
    :ets.insert(Tables.index(), {key})
    unless member?(key), do: :ets.delete(Tables.index(), key)
  end

  # For a keyed record, the older tuple with the same key goes (or this
  # one, if a newer one is there already). The new record is stored before
  # the old one is removed, so a reader sees one or (for an instant) both,
  # never neither.
  defp claim({_key, _tuple, nil, _expires, _stamp}), do: :ok

  defp claim({key, _tuple, key_bin, _expires, stamp}) do
    losers = claim_key(key_bin, {key, stamp}, [])
    Enum.each(losers, &remove/1)
    if key in losers, do: :stale, else: :ok
  end

  # Lock-free claim of the latest-value index. :ets.take hands the entry
  # there to exactly one writer, which compares it with its candidate, and
  # :ets.insert_new lets exactly one writer install the winner; a writer
  # that finds another's entry installed meanwhile takes and compares that
  # one too. Every entry taken is compared once, so the index ends on the
  # newest record and each writer returns the record keys that lost in its
  # hands (its own among them when it was stale), which it deletes. A writer
  # that finds its own record installed (a record settled twice) puts it
  # back.
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
        if newer?(stamp, old_stamp) or not member?(old_key),
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

  # Removes the record `key` and its index entry; its row if it was here.
  defp remove(key) do
    case :ets.take(Tables.tuples(), row_key(key)) do
      [row] ->
        :ets.delete(Tables.index(), key)
        row

      [] ->
        nil
    end
  end

  ## Removing

  @doc false
  # Removes a record (a replica told of a take, a stale replica); true if
  # it was here.
  @spec delete(tuple()) :: boolean()
  def delete(key) do
    case remove(key) do
      {_row_key, _tuple, key_bin, _expires, _stamp} ->
        forget_key(key_bin, key)
        true

      nil ->
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
  # Every template reads through the index, so that matches come in one
  # order: by arity, tag and robot id in term order, then oldest first. A
  # template that binds a stream (tag and robot) walks that stream's range
  # with ets:next, where a select would compile its match specification on
  # every call (a warm rdp 1.9 us by select, 1.5 us by walking); one that
  # binds a tag, or only the arity, selects that range; a match
  # specification selects every key. Each candidate is then looked up and
  # matched exactly (1 and 1.0 sort together in the index).
  #
  # Reads look in the index, then in fresh, then in the index again: a
  # write settled while the first walk was past it and before fresh was
  # read is in the index by then (settling indexes before it leaves fresh).

  @doc false
  @spec first_match(Template.compiled()) :: {:ok, tuple()} | :none
  def first_match(template) do
    case matches(template, 1) do
      {[{_key, tuple} | _], _next} -> {:ok, tuple}
      :done -> :none
    end
  end

  @doc false
  @spec all_matches(Template.compiled()) :: [tuple()]
  def all_matches(%Template{index: :spec} = template) do
    {found, _} = spec_matches(template)
    Enum.map(found, &elem(&1, 1))
  end

  def all_matches(template) do
    # fresh first, then the index: a write found in neither was settled
    # after the index was read, so after this call began
    now = now()

    (candidate_keys(Tables.fresh(), template) ++ candidate_keys(Tables.index(), template))
    |> Enum.sort()
    |> Enum.dedup()
    |> Enum.flat_map(fn key ->
      case live_match(key, template, now) do
        {:ok, tuple} -> [tuple]
        :none -> []
      end
    end)
  end

  @doc false
  @spec all_tuples() :: [tuple()]
  def all_tuples do
    :ets.select(Tables.tuples(), [{{:_, :"$1", :_, :"$2", :_}, [{:>, :"$2", now()}], [:"$1"]}])
  end

  # Live matches of `template`, oldest first, `size` at first and then a
  # batch at a time: {[{key, tuple}], next} where next.() gives the next
  # ones, or :done.
  defp matches(%Template{index: :spec} = template, _size) do
    case spec_matches(template) do
      {[], _} -> :done
      found -> found
    end
  end

  defp matches(template, size) do
    again = fn -> scan(Tables.index(), template, @batch, fn -> :done end) end
    fresh = fn -> scan(Tables.fresh(), template, @batch, again) end
    scan(Tables.index(), template, size, fresh)
  end

  # A match specification runs over every record in one select (ETS runs
  # it in C, where walking the index would look each record up), whose
  # matches are then put in index order.
  defp spec_matches(template) do
    ms = Template.record_match_spec(template, now(), {{{:element, 1, :"$_"}, :"$_"}})
    # the row's key comes first, then the whole row
    found =
      for {row_key, {_, tuple, _, _, _}} <- :ets.select(Tables.tuples(), ms),
          do: {identity(row_key, tuple), tuple}

    {Enum.sort(found), fn -> :done end}
  end

  defp scan(table, %Template{index: {:stream, n, first, second}} = template, size, then),
    do: walk(table, {n, first, second, 0, nil}, template, size, then)

  defp scan(table, template, size, then) do
    if table == Tables.fresh() and :ets.first(table) == :"$end_of_table",
      do: then.(),
      else: pick(:ets.select(table, Template.index_match_spec(template), size), template, then)
  end

  defp walk(table, from, template, size, then) do
    case walk_keys(table, from, template, now(), size, []) do
      {[], _last, :end} -> then.()
      {found, _last, :end} -> {found, then}
      {found, last, :more} -> {found, fn -> walk(table, last, template, @batch, then) end}
    end
  end

  # up to `left` live matches after `from` in the stream's range, oldest
  # first, the last key looked at, and whether the range goes on
  defp walk_keys(_table, from, _template, _now, 0, acc), do: {Enum.reverse(acc), from, :more}

  defp walk_keys(table, from, %Template{index: {:stream, n, first, second}} = t, now, left, acc) do
    case :ets.next(table, from) do
      {^n, f, s, _, _} = key when f == first and s == second ->
        case live_match(key, t, now) do
          {:ok, tuple} -> walk_keys(table, key, t, now, left - 1, [{key, tuple} | acc])
          :none -> walk_keys(table, key, t, now, left, acc)
        end

      _end_of_stream ->
        {Enum.reverse(acc), from, :end}
    end
  end

  defp pick(:"$end_of_table", _template, then), do: then.()

  defp pick({keys, cont}, template, then) do
    now = now()
    found = for key <- keys, {:ok, tuple} <- [live_match(key, template, now)], do: {key, tuple}
    next = fn -> pick(:ets.select(cont), template, then) end
    if found == [], do: next.(), else: {found, next}
  end

  # every key in `table` (index or fresh) under the template's stream or tag
  defp candidate_keys(table, %Template{index: {:stream, n, first, second}}),
    do: stream_keys(table, {n, first, second, 0, nil}, [])

  defp candidate_keys(table, template),
    do: :ets.select(table, Template.index_match_spec(template))

  defp stream_keys(table, {n, first, second, _, _} = from, acc) do
    case :ets.next(table, from) do
      {^n, f, s, _, _} = key when f == first and s == second ->
        stream_keys(table, key, [key | acc])

      _end_of_stream ->
        acc
    end
  end

  defp live_match(key, template, now) do
    case :ets.lookup(Tables.tuples(), row_key(key)) do
      [{_, tuple, _, expires, _}] when expires > now ->
        if Template.matches?(template, tuple), do: {:ok, tuple}, else: :none

      _gone_or_expired ->
        :none
    end
  end

  ## Taking

  @doc false
  # Linda `inp`: the oldest matching tuple this node owns, else the oldest of
  # another node's, taken through its owner so that exactly one taker in the
  # cluster gets it.
  @spec take_first(Template.compiled()) :: {:ok, tuple()} | :none
  def take_first(template) do
    # The oldest match alone first: it is this node's more often than not,
    # and finding 16 costs 3x finding one. Otherwise batches of 16, this
    # node's taken first, as remote takes cost a round trip.
    case matches(template, 1) do
      {[{key, _tuple}], _next} ->
        if key_owner(key) == node(),
          do: take_from({[key], fn -> keys(matches(template, @batch)) end}),
          else: take_from(keys(matches(template, @batch)))

      {_found, _next} ->
        take_from(keys(matches(template, @batch)))

      :done ->
        :none
    end
  end

  defp keys(:done), do: :done
  defp keys({found, next}), do: {Enum.map(found, &elem(&1, 0)), fn -> keys(next.()) end}

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
    case :ets.take(Tables.tuples(), row_key(key)) do
      [{_row_key, tuple, key_bin, expires, _stamp}] ->
        :ets.delete(Tables.index(), key)
        forget_key(key_bin, key)
        ThinkingCap.Blackboard.Core.Server.taken(key)
        if expires > now(), do: {:ok, tuple}, else: :gone

      [] ->
        :gone
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
  def member?(key), do: :ets.member(Tables.tuples(), row_key(key))

  @doc false
  # Every live record this node owns, as wire records, oldest first (the
  # table orders them by owner, then seq).
  @spec owned_snapshot() :: [wire()]
  def owned_snapshot do
    now = now()
    ms = [{{{node(), :_}, :_, :_, :"$1", :_}, [{:>, :"$1", now}], [:"$_"]}]

    for row <- :ets.select(Tables.tuples(), ms), do: row |> to_record() |> to_wire()
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
    for {row_key, tuple} <-
          :ets.select(Tables.tuples(), [
            {{{owner, :_}, :"$1", :_, :_, :_}, [], [{{{:element, 1, :"$_"}, :"$1"}}]}
          ]),
        do: identity(row_key, tuple)
  end

  @doc false
  # Forgets every tuple owned by `owner` (its node went away).
  @spec purge(node()) :: non_neg_integer()
  def purge(owner) do
    count = :ets.select_delete(Tables.tuples(), [{{{owner, :_}, :_, :_, :_, :_}, [], [true]}])
    :ets.select_delete(Tables.index(), [{{owner_key(owner)}, [], [true]}])
    :ets.select_delete(Tables.keys(), [{{:_, owner_key(owner), :_}, [], [true]}])
    count
  end

  @doc false
  # Deletes expired records and old tombstones, and settles the writes that
  # were staged at the last sweep already (their writer was killed between
  # staging and settling); returns how many records expired.
  @spec sweep() :: non_neg_integer()
  def sweep do
    now = now()
    :ets.select_delete(Tables.tombs(), [{{:_, :"$1"}, [{:<, :"$1", now - 60_000}], [true]}])
    ms = [{{:"$1", :"$2", :"$3", :"$4", :_}, [{:"=<", :"$4", now}], [{{:"$1", :"$2", :"$3"}}]}]
    expired = :ets.select(Tables.tuples(), ms)

    for {row_key, tuple, key_bin} <- expired do
      key = identity(row_key, tuple)
      remove(key)
      forget_key(key_bin, key)
    end

    settle_abandoned()
    length(expired)
  end

  defp settle_abandoned do
    staged = for {key} <- :ets.tab2list(Tables.fresh()), do: key
    seen = MapSet.new(:ets.lookup_element(Tables.meta(), :staged_at_sweep, 2))
    {abandoned, recent} = Enum.split_with(staged, &MapSet.member?(seen, &1))

    for key <- abandoned do
      case :ets.lookup(Tables.tuples(), row_key(key)) do
        [row] -> settle(to_record(row))
        [] -> :ets.delete(Tables.fresh(), key)
      end
    end

    :ets.insert(Tables.meta(), {:staged_at_sweep, recent})
  end
end
