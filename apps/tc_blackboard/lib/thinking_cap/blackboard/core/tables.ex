defmodule ThinkingCap.Blackboard.Core.Tables do
  @moduledoc false
  # Owns the blackboard's ETS tables and does nothing else, so that the
  # tables outlive every process that serves them: a crash of the server
  # loses no tuple, subscription or blocked waiter.
  #
  #   tuples   ordered_set  {key, tuple, key_bin | nil, expires, stamp | nil}
  #                         key = {arity, first, second, seq, owner_node}
  #   fresh    ordered_set  {key, tuple, key_bin | nil, expires, stamp | nil, writer_pid}
  #                         (see Store for the two)
  #   keys     set          {key_bin, {arity, first, second, seq, owner}, stamp}
  #                         latest-value index
  #   subs     bag          {index, ref, pid, matcher, max_queue, on_overflow, slot}
  #   sub_refs set          {ref, index, pid, dropped, template}
  #   waiters  ordered_set  {{index, wseq}, pid, ref, kind, template, woken?}
  #   tombs    set          {record_key, at_ms}  deletes that overtook their insert
  #   meta     set          {:boot, id}, {:peers, [server_pid]},
  #                         {{:watermark, node}, boot, seq}
  #   (and two arrays in persistent_term: counters/0 and send_counts/0)

  use GenServer

  @tuples :tc_bb_tuples
  @fresh :tc_bb_fresh
  @keys :tc_bb_keys
  @subs :tc_bb_subs
  @sub_refs :tc_bb_sub_refs
  @waiters :tc_bb_waiters
  @tombs :tc_bb_tombs
  @meta :tc_bb_meta

  def tuples, do: @tuples
  def fresh, do: @fresh
  def keys, do: @keys
  def subs, do: @subs
  def sub_refs, do: @sub_refs
  def waiters, do: @waiters
  def tombs, do: @tombs
  def meta, do: @meta

  @doc false
  def boot_id, do: :ets.lookup_element(@meta, :boot, 2)

  @counters [any_subs: 1, spec_subs: 2, peers: 3, waiters: 4]
  @tag_buckets 1024
  @tag_base length(@counters)

  @doc false
  # Counters the write path reads instead of probing tables: subscriptions
  # indexed by arity only ({:any, n}) and by match specification (:spec), so
  # delivery skips those lookups when there are none; the number of peer
  # servers; an upper bound on the number of blocked waiters (see
  # `Waiters.any?/1`); and, in #{@tag_buckets} buckets by `tag_bucket/2`, subscriptions
  # indexed by tag only ({:tag, n, first}), so that a write looks for them
  # only when its tag's bucket holds some (a bucket shared by two tags costs
  # a needless lookup, never a missed delivery). One array per table
  # set, found through persistent_term (written once per start of this
  # process). `counter/1` names the fixed slots. A :counters array, not an
  # :atomics one: its get is a BIF where atomics' is a NIF call, 10 ns
  # against 45 ns (measured here), and a write reads five of them.
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

  @doc false
  # The counter slot of tag-only subscriptions to tuples of arity `n` whose
  # first element is `first`.
  # (An atom's hash is stored with it: phash2 of `first` alone costs 20 ns,
  # of `{n, first}` 60 ns.)
  def tag_bucket(n, first), do: @tag_base + 1 + rem(:erlang.phash2(first) + n, @tag_buckets)

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
    :ets.new(@tuples, [:ordered_set | concurrent])
    :ets.new(@fresh, [:ordered_set | plain])
    :ets.new(@keys, [:set | concurrent])
    :ets.new(@subs, [:bag | plain])
    :ets.new(@sub_refs, [:set | plain])
    :ets.new(@waiters, [:ordered_set | plain])
    :ets.new(@tombs, [:set | plain])
    :ets.new(@meta, [:set, {:read_concurrency, true} | plain])

    :ets.insert(@meta, [
      {:boot, {System.system_time(), :erlang.unique_integer()}},
      {:peers, []}
    ])

    :persistent_term.put({__MODULE__, :counters}, :counters.new(@tag_base + @tag_buckets, []))
    :persistent_term.put({__MODULE__, :send_counts}, :atomics.new(@send_slots, signed: false))

    {:ok, nil}
  end
end
