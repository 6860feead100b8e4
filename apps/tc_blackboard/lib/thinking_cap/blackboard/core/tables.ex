defmodule ThinkingCap.Blackboard.Core.Tables do
  @moduledoc false
  # Owns the blackboard's ETS tables, and the flags that tell writers which
  # kinds of subscription exist, and does nothing else, so that the tables
  # outlive every process that serves them: a crash of the server loses no
  # tuple, subscription or blocked waiter.
  #
  #   tuples   ordered_set  {key, tuple, key_bin | nil, expires, stamp | nil}
  #                         key = {arity, first, second, seq, owner_node}
  #   fresh    ordered_set  {key, tuple, key_bin | nil, expires, stamp | nil, writer_pid}
  #                         (see Store for the two)
  #   keys     set          {key_bin, {arity, first, second, seq, owner}, stamp}
  #                         latest-value index
  #   subs     bag          {index, ref, pid, matcher, max_queue, on_overflow, slot,
  #                          batch}  (batch: nil, or {max_batch, max_delay_ms})
  #   sub_refs set          {ref, index, pid, dropped, template}
  #   waiters  ordered_set  {{index, wseq}, pid, ref, kind, template, woken?}
  #   tombs    set          {record_key, at_ms}  deletes that overtook their insert
  #   meta     set          {:boot, id}, {:peers, [server_pid]},
  #                         {{:watermark, node}, boot, seq}
  #   batches  set          {ref, next, taken, pid, max_batch, max_delay_ms, max_queue,
  #                          notified, gap}  a batched subscription (see Batches)
  #   batched  ordered_set  {{ref, position}, tuple | :dropped, monotonic_time}
  #                         the tuples held for batched subscriptions
  #   (and in persistent_term: the tables' ids, two arrays, counters/0 and
  #   send_counts/0, and the index flags, tag_indexed?/2 and wide_indexed/0)

  use GenServer

  # Named, so that they can be inspected (`:ets.i/0`), but reached through
  # their ids: an access by name first looks the name up in the node's name
  # table, which, cold, costs a write about 0.2 of a raw send's latency
  # (measured in the benchmark's write path).
  @names [
    tuples: :tc_bb_tuples,
    fresh: :tc_bb_fresh,
    keys: :tc_bb_keys,
    subs: :tc_bb_subs,
    sub_refs: :tc_bb_sub_refs,
    waiters: :tc_bb_waiters,
    tombs: :tc_bb_tombs,
    meta: :tc_bb_meta,
    batches: :tc_bb_batches,
    batched: :tc_bb_batched
  ]
  @ids {__MODULE__, :ids}

  for {{table, _name}, i} <- Enum.with_index(@names) do
    def unquote(table)(), do: elem(:persistent_term.get(@ids), unquote(i))
  end

  @doc false
  def boot_id, do: :ets.lookup_element(meta(), :boot, 2)

  @counters [peers: 1, waiters: 2]

  @doc false
  # Counters the write path reads instead of probing tables: the number of
  # peer servers and an upper bound on the number of blocked waiters (see
  # `Waiters.any?/1`). One array per table set, found through
  # persistent_term (written once per start of this process). `counter/1`
  # names the slots. A :counters array, not an :atomics one: its get is a
  # BIF where atomics' is a NIF call.
  def counters, do: :persistent_term.get({__MODULE__, :counters})

  @send_slots 65_536

  @doc false
  # Per-subscription send counts (see `Subscriptions`), one word per slot of
  # #{@send_slots}; a subscription's slot is `send_slot/1` of its ref.
  # An array shared by every subscription: a reference to an array of its
  # own, stored in its subscription row, costs ~200 ns on every delivery
  # (copying a magic reference out of ETS bumps its reference count).
  def send_counts, do: :persistent_term.get({__MODULE__, :send_counts})

  @doc false
  def send_slot(ref), do: :erlang.phash2(ref, @send_slots) + 1

  @doc false
  def counter(name), do: Keyword.fetch!(@counters, name)

  ## Index flags

  @tag_buckets 1024
  @any 1
  @spec_bit 2

  @doc false
  # Whether writes must look for subscriptions indexed by tag only
  # ({:tag, n, first}): true while one of the tags in `first`'s bucket of
  # #{@tag_buckets} has one (a bucket shared by two tags costs a needless
  # lookup, never a missed delivery). Flags are persistent terms holding
  # true or false: a get costs a few ns where a :counters get costs 40-60,
  # and replacing an immediate value starts no global garbage collection.
  # (An atom's hash is stored with it: phash2 of `first` alone costs 20 ns,
  # of `{n, first}` 60 ns.)
  def tag_indexed?(n, first),
    do: :persistent_term.get({__MODULE__, :tag, tag_bucket(n, first)}, false)

  @doc false
  def tag_bucket(n, first), do: rem(:erlang.phash2(first) + n, @tag_buckets)

  @doc false
  # Whether writes must look for subscriptions indexed by arity only
  # ({:any, n}) and by match specification (:spec): `{any?, spec?}`.
  def wide_indexed do
    flags = :persistent_term.get({__MODULE__, :wide}, 0)
    {Bitwise.band(flags, @any) != 0, Bitwise.band(flags, @spec_bit) != 0}
  end

  @doc false
  # Counts a subscription added (+1) or removed (-1) under `index`, and
  # raises or lowers the flag the write path reads. Flags change in this
  # process alone, so two subscribers never race on one. Called after a
  # subscription's row is inserted and after it is deleted: a subscription
  # is flagged from before its `subscribe/2` returns to after it is gone.
  @spec count_subscription(term(), 1 | -1) :: :ok | {:error, :unknown_index}
  def count_subscription({:stream, _, _, _}, _delta), do: :ok

  def count_subscription(index, delta) when delta in [1, -1],
    do: GenServer.call(__MODULE__, {:count, index, delta}, :infinity)

  defp flag_of({:tag, n, first}), do: {:tag, tag_bucket(n, first)}
  defp flag_of({:any, _n}), do: {:wide, @any}
  defp flag_of(:spec), do: {:wide, @spec_bit}
  defp flag_of(_unknown), do: nil

  defp set_flag({:tag, bucket}, on?), do: :persistent_term.put({__MODULE__, :tag, bucket}, on?)

  defp set_flag({:wide, bit}, on?) do
    flags = :persistent_term.get({__MODULE__, :wide}, 0)
    new = if on?, do: Bitwise.bor(flags, bit), else: Bitwise.band(flags, Bitwise.bnot(bit))
    :persistent_term.put({__MODULE__, :wide}, new)
  end

  # flags left by an earlier incarnation of this process (its subscriptions
  # went with its tables)
  defp clear_flags do
    for {{__MODULE__, kind, _} = key, _} <- :persistent_term.get(),
        kind == :tag,
        do: :persistent_term.erase(key)

    :persistent_term.erase({__MODULE__, :wide})
  end

  def start_link(_opts), do: GenServer.start_link(__MODULE__, :ok, name: __MODULE__)

  @impl true
  def init(:ok) do
    # Keys are written by every keyed out, from many schedulers: that table
    # takes the concurrency options too. Subscriptions and waiters are read by
    # every out but seldom written; there the options cost 3-4x per read
    # (a missing-key lookup 145 ns against 45 ns, ets:first 125 ns against
    # 30 ns, measured here), so they are plain tables.
    concurrent = [:public, :named_table, read_concurrency: true, write_concurrency: true]
    plain = [:public, :named_table]
    # Tuples are written by every out, from every scheduler: a write lock
    # on a plain tree is cheaper alone (an insert 300 ns against 550 ns,
    # measured here) but held against every other writer and reader, and
    # the example robot missed 3-5x more deadlines with it. Fresh holds a
    # handful of rows for a few microseconds each.
    options = [
      tuples: [:ordered_set | concurrent],
      fresh: [:ordered_set | plain],
      keys: [:set | concurrent],
      subs: [:bag | plain],
      sub_refs: [:set | plain],
      waiters: [:ordered_set | plain],
      tombs: [:set | plain],
      meta: [:set, {:read_concurrency, true} | plain],
      # every write a batched subscription matches takes a position here
      # and inserts there, from many schedulers
      batches: [:set, :public, :named_table, write_concurrency: true],
      batched: [:ordered_set, :public, :named_table, write_concurrency: true]
    ]

    ids =
      for {table, name} <- @names do
        :ets.new(name, Keyword.fetch!(options, table))
        :ets.whereis(name)
      end

    :persistent_term.put(@ids, List.to_tuple(ids))
    clear_flags()

    :ets.insert(meta(), [
      {:boot, {System.system_time(), :erlang.unique_integer()}},
      {:peers, []}
    ])

    :persistent_term.put({__MODULE__, :counters}, :counters.new(length(@counters), []))
    :persistent_term.put({__MODULE__, :send_counts}, :atomics.new(@send_slots, signed: false))

    {:ok, %{}}
  end

  # Every call is answered and none can fail: this process holds the tables.
  @impl true
  def handle_call({:count, index, delta}, _from, counts) when delta in [1, -1] do
    case flag_of(index) do
      nil -> {:reply, {:error, :unknown_index}, counts}
      flag -> {:reply, :ok, count(counts, flag, delta)}
    end
  end

  def handle_call(_other, _from, counts), do: {:reply, {:error, :unknown_call}, counts}

  defp count(counts, flag, delta) do
    before = Map.get(counts, flag, 0)
    now = before + delta

    cond do
      before == 0 and now > 0 -> set_flag(flag, true)
      before > 0 and now == 0 -> set_flag(flag, false)
      true -> :ok
    end

    if now == 0, do: Map.delete(counts, flag), else: Map.put(counts, flag, now)
  end
end
