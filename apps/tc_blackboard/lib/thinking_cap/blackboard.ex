defmodule ThinkingCap.Blackboard do
  @moduledoc """
  The communication layer: a Linda tuple space shared by every process of
  every connected node, with event subscriptions.

  Modules never talk to each other directly; they write tuples and read,
  take or subscribe to the tuples they need. By convention a tuple is
  `{tag, robot_id, payload_map}`, so `{:scan, :_, :_}` selects every robot's
  scans:

      :ok = Blackboard.out({:pose, :r1, %{x: 1.0, y: 2.0, theta: 0.0}}, key: {:pose, :r1})
      {:ok, {:pose, :r1, pose}} = Blackboard.rd({:pose, :r1, :_})
      {:ok, ref} = Blackboard.subscribe({:scan, :r1, :_})
      receive do
        {:blackboard, ^ref, {:scan, :r1, scan}} -> scan
      end

  Templates are described in `ThinkingCap.Blackboard.Template`. Bad input
  (a non-tuple, a malformed template or match specification, an unknown
  option) raises `ArgumentError` saying what was wrong.

  ## Consistency model

  **Ownership.** Every tuple is owned by the node where it was written. The
  owner's table is the authority on whether it still exists; every other
  node holds a replica for reading and for its own subscribers.

  **Local writes are visible at once.** When `out/2` returns, every process
  on the same node can read or take the tuple, and local subscribers have
  been sent it. Subscribers come first: a write that local subscribers
  match is readable before they are sent it, and the writer (unless it
  runs at high priority, as periodic modules do) then yields its scheduler
  so that they run before it finishes the write (a take of the tuple in
  that moment waits for it to finish).

  **Other nodes see a write after one message hop.** Each write goes to
  every other node's blackboard server (through this node's replicator, so
  that the writer never waits on the network), which applies it and
  delivers it to its subscribers and blocked waiters. `out/2` never waits
  for other nodes; there is no cluster-wide commit.

  **Order.** Erlang keeps the order of messages between two processes, and
  each node has one replicator, so the tuples of one writer reach every
  reader, subscriber and node in the order they were written. No order is promised between different
  writers.

  **Which tuple.** Tuples are indexed by arity and their first two
  elements (tag and robot id by convention): `rd`/`rdp` return the oldest
  matching tuple of the first matching tag and robot id in Erlang term
  order, so the tuples of one stream come oldest first. A template that
  binds the first two elements walks only that stream.

  **Exactly-once take.** Whoever takes a tuple, on whichever node, the
  owner's atomic table operation decides: exactly one taker gets it. A
  taker prefers its own node's tuples (no round trip), in the order above,
  then the others', which it takes through a call to the owner node. Such
  a call ends when the owner answers or its node disconnects.

  **Read and take.** A tuple may be taken on its owner before a reader on
  another node saw it. Subscribers on every connected node still receive
  every write, taken or not.

  **Latest-value keys.** `out(tuple, key: k)` replaces the tuple written
  last with key `k`. Writers of one key on different nodes resolve by
  last-writer-wins (wall-clock time, then node name), so every node keeps
  the same one. A reader sees the new tuple, the old one, or for an instant
  both, never neither.

  **Time to live.** `out(tuple, ttl: ms)` expires `ms` milliseconds after
  each node received the tuple, by that node's monotonic clock. An expired
  tuple is never returned; it is removed within half a second.

  **A node that dies takes its tuples with it.** When a node goes down,
  every other node forgets the tuples it owned, so that a dead sensor node's
  last scan cannot steer the robot; their subscribers are not told. Every
  other tuple stays, takes stay exactly-once, blocked waiters keep waiting.

  **Partitions.** While nodes are cut off from each other, each side sees
  only the tuples owned on its side (the others are forgotten, as for a
  dead node), and takes only those: nothing is taken twice. When the nodes
  reconnect their servers exchange full snapshots of the tuples they own:
  each side then holds the other side's current tuples, including those
  written during the partition, and its subscribers and waiters receive
  those written during the partition (not again those they saw before it).
  Tuples taken during the partition stay gone.

  **Server crashes.** The tables belong to a process that runs no other
  code. The server and the replicator that serve them can crash without
  losing a tuple, a subscription or a blocked waiter: blocked waiters are
  rows in a table, and a woken taker takes for itself, so no tuple is ever
  in a server's hands. On restart the server rescans the waiters, monitors
  the subscribers again and exchanges snapshots with every other node,
  which repairs whatever was in its own or the replicator's mailbox.

  **Subscribers.** Delivery never blocks the writer. Each subscription has
  a bound, `max_queue` (default 1000): while the subscriber's mailbox
  holds that many messages (checked every `max_queue/64` tuples, and at
  every tuple while it is full, so the bound holds to within 1/64, and
  one, for each writer writing at that moment; exactly below 128), tuples
  for it are dropped and counted (`on_overflow: :drop`, the default; see
  `dropped/1`) or it is unsubscribed and sent `{:blackboard_overflow, ref}`
  (`on_overflow: :disconnect`). The subscriptions of a process that exits
  are removed, with the tuples held for them.

  **Batched subscribers.** A subscriber that takes many tuples a second
  can ask for them in lists (`subscribe(t, batch: true)`): its tuples
  are held on its node, and it is sent `{:blackboard_held, ref}` when
  `max_batch` are held or `max_delay_ms` after the first; it then takes
  them, `take_held(ref)`, `[{tuple, at}]` oldest first (`at` is the
  node's `System.monotonic_time/0` when the tuple was held, when it
  would have been sent). The order is the one above: the tuples of one
  writer come in the order written, in one list or in lists that follow
  each other; none comes twice and none is left out, but for a writer
  killed in the middle of its write (its tuple may be lost, as an
  unbatched subscriber may miss it, and the lists wait up to a second
  for it). One notice at a time is sent: until the subscriber takes,
  the tuples wait. Writers do not yield to batched subscribers, whom
  they do not wake. `max_queue` bounds the tuples held (beyond it they
  are dropped or the subscription ends, as `on_overflow` says).
  With `hold: {module, function}` the writer holds what
  `module.function(tuple)` returns instead of the tuple (the tuple
  itself if it raises), and `take_held/1` gives that: a subscriber can
  have its tuples held as it needs them, made once by their writer,
  which copies what it holds anyway.

  Inspect the space from a shell with `ThinkingCap.Blackboard.IEx`.
  """

  alias ThinkingCap.Blackboard.Core.{
    Batches,
    EvalSupervisor,
    Server,
    Store,
    Subscriptions,
    Tables,
    Waiters
  }

  alias ThinkingCap.Blackboard.Template
  require Logger

  @default_max_queue 1000

  @type template :: Template.t()
  @type out_option :: {:key, term()} | {:ttl, pos_integer()}
  @default_max_batch 64
  @default_max_delay_ms 20

  @type subscribe_option ::
          {:max_queue, pos_integer()}
          | {:on_overflow, :drop | :disconnect}
          | {:batch, boolean()}
          | {:max_batch, pos_integer()}
          | {:max_delay_ms, pos_integer()}
          | {:hold, {module(), atom()}}

  @doc """
  Writes `tuple`.

  Options:
    * `:key` - latest-value key: replaces the tuple last written with the
      same key (`nil` means no key);
    * `:ttl` - time to live in milliseconds.

  A write that local subscribers match yields the caller's scheduler once
  (`:erlang.yield/0`) after sending them the tuple, so that those that
  wait on the same scheduler run before the writer finishes its own
  bookkeeping; the tuple can be read and taken before they are sent it.
  Processes at high or max priority (periodic modules) do not yield.
  """
  @spec out(tuple(), [out_option()]) :: :ok
  def out(tuple, opts \\ [])

  def out(tuple, opts) when is_tuple(tuple) and is_list(opts) do
    {ukey, ttl} = out_options(opts)
    record = Store.new_record(tuple, ukey, ttl)
    counters = Tables.counters()

    recipients = Subscriptions.recipients(tuple)

    if recipients == [] and ukey == nil do
      Store.insert(record)
      tell_others(record, tuple, counters)
    else
      # Staged, the tuple can be read and taken: nothing else must stand
      # before the subscribers' send. The writer then yields to the
      # subscribers it woke on its own scheduler, and after they ran tells
      # blocked waiters and the other nodes, and settles the write (into
      # the tuple table, replacing its latest-value key's older tuple). A
      # keyed write is staged even when nobody is sent it: a writer killed
      # before its key is claimed leaves its fresh row, and the sweeper
      # finishes the claim, where a write stored in one step would stay
      # beside the key's newer tuple.
      Store.stage(record)

      if recipients != [] do
        due = Subscriptions.send_to(recipients, tuple)
        if Subscriptions.wakes?(recipients), do: yield_to_subscribers()
        Subscriptions.check_queues(due)
      end

      tell_others(record, tuple, counters)
      Store.settle(record)
    end

    :ok
  end

  def out(tuple, opts) when is_tuple(tuple) do
    raise ArgumentError,
          "ThinkingCap.Blackboard.out/2 options must be a keyword list, got: #{inspect(opts)}"
  end

  def out(other, _opts) do
    raise ArgumentError, "ThinkingCap.Blackboard.out/2 writes tuples, got: #{inspect(other)}"
  end

  # High-priority processes (periodic modules, the cycle) do not yield: a
  # yield lets every other high-priority process run first, and their own
  # deadline counts for more than a subscriber's latency.
  defp yield_to_subscribers do
    case :erlang.process_info(self(), :priority) do
      {:priority, priority} when priority in [:high, :max] -> :ok
      _normal_or_low -> :erlang.yield()
    end
  end

  # Blocked waiters and the other nodes, once the tuple can be found: a
  # waiter counts itself before it looks, so one of the two sees the other.
  defp tell_others(record, tuple, counters) do
    if Waiters.any?(counters), do: Server.notify({:arrived, tuple})
    Server.replicate(record, counters)
  end

  @doc """
  Reads a tuple matching `template`, waiting up to `timeout` ms for one.
  """
  @spec rd(template(), timeout()) :: {:ok, tuple()} | {:error, :timeout}
  def rd(template, timeout \\ :infinity) do
    compiled = Template.compile(template)
    Waiters.await(:rd, compiled, check_timeout(timeout), fn -> Store.first_match(compiled) end)
  end

  @doc "Reads a tuple matching `template` if there is one; never waits."
  @spec rdp(template()) :: {:ok, tuple()} | :none
  def rdp(template), do: template |> Template.compile() |> Store.first_match()

  @doc """
  Takes (Linda `in`) a tuple matching `template`, waiting up to `timeout`
  ms for one. Blocked takers of the same template on one node are served in
  the order they arrived.
  """
  @spec take(template(), timeout()) :: {:ok, tuple()} | {:error, :timeout}
  def take(template, timeout \\ :infinity) do
    compiled = Template.compile(template)
    Waiters.await(:take, compiled, check_timeout(timeout), fn -> Store.take_first(compiled) end)
  end

  @doc """
  Takes (Linda `inp`) a tuple matching `template` if there is one. It does
  not wait for one to be written, but taking another node's tuple is a
  round trip to that node.
  """
  @spec takep(template()) :: {:ok, tuple()} | :none
  def takep(template), do: template |> Template.compile() |> Store.take_first()

  @doc "Every tuple matching `template`."
  @spec rd_all(template()) :: [tuple()]
  def rd_all(template), do: template |> Template.compile() |> Store.all_matches()

  @doc """
  Runs `fun` (a 0-arity function or `{module, function, args}`) in a
  supervised process and writes the tuple it returns. A crash, or a result
  that is not a tuple, is logged and written as
  `{:eval_error, node(), %{pid: pid, function: description, reason: text}}`.
  """
  @spec eval((() -> tuple()) | {module(), atom(), list()}) :: {:ok, pid()}
  def eval(fun) when is_function(fun, 0), do: start_eval(fun, inspect(fun))

  def eval({m, f, a} = mfa) when is_atom(m) and is_atom(f) and is_list(a) do
    start_eval(
      fn -> apply(m, f, a) end,
      Exception.format_mfa(m, f, length(a)) <> " " <> inspect(mfa, limit: 5)
    )
  end

  def eval(other) do
    raise ArgumentError,
          "ThinkingCap.Blackboard.eval/1 takes a 0-arity function or {module, function, args}, got: " <>
            inspect(other)
  end

  defp start_eval(fun, description) do
    Task.Supervisor.start_child(EvalSupervisor, fn -> run_eval(fun, description) end)
  end

  defp run_eval(fun, description) do
    case fun.() do
      tuple when is_tuple(tuple) -> out(tuple)
      other -> report_eval(description, "returned #{inspect(other)}, not a tuple")
    end
  catch
    kind, reason -> report_eval(description, Exception.format(kind, reason, __STACKTRACE__))
  end

  defp report_eval(description, reason) do
    Logger.error("blackboard eval of #{description} failed: #{reason}")
    out({:eval_error, node(), %{pid: self(), function: description, reason: reason}})
  end

  @doc """
  Subscribes the calling process to every later write matching `template`,
  on any node. Each arrives as `{:blackboard, ref, tuple}`.

  Options: `:max_queue` (default #{@default_max_queue}) and `:on_overflow`
  (`:drop`, the default, or `:disconnect`); see the moduledoc.

  With `batch: true` the tuples are held instead, and the subscriber is
  sent `{:blackboard_held, ref}` when `:max_batch` tuples (default
  #{@default_max_batch}) are held or `:max_delay_ms` (default
  #{@default_max_delay_ms}) after the first of them; `take_held/1` gives
  them (see "Batched subscribers" in the moduledoc). With `hold:
  {module, function}` each is held as `module.function(tuple)` returns
  it (the tuple itself if that raises); the writer runs it, so it must be
  quick and must not depend on the subscriber's process:

      {:ok, ref} = Blackboard.subscribe({:scan, :r1, :_}, batch: true, max_delay_ms: 100)
      receive do
        {:blackboard_held, ^ref} -> for {scan, _at} <- Blackboard.take_held(ref), do: scan
      end

  Cost to writers: a template that binds the first two elements (a stream,
  such as `{:scan, :r1, :_}`) is found by the lookup every write makes of
  its own stream. One that binds only the tag, binds neither, or is a
  match specification adds a lookup to every write it may match (for a
  tag, the writes of the tags that share its hash bucket), for as long
  as it exists.
  """
  @spec subscribe(template(), [subscribe_option()]) :: {:ok, reference()}
  def subscribe(template, opts \\ []) do
    compiled = Template.compile(template)
    {max_queue, on_overflow, batch} = subscribe_options(opts)
    {:ok, Subscriptions.subscribe(compiled, self(), max_queue, on_overflow, batch)}
  end

  @doc """
  Cancels a subscription. Messages for it already in the caller's mailbox
  are removed.
  """
  @spec unsubscribe(reference()) :: :ok
  def unsubscribe(ref) when is_reference(ref) do
    Subscriptions.unsubscribe(ref)
    flush_subscription(ref)
  end

  defp flush_subscription(ref) do
    receive do
      {:blackboard, ^ref, _} -> flush_subscription(ref)
      {:blackboard_held, ^ref} -> flush_subscription(ref)
    after
      0 -> :ok
    end
  end

  @doc """
  The tuples held for the caller's batched subscription `ref`, oldest
  first, as `[{tuple, at}]` (`tuple` as `hold:` made it, if the
  subscription has one; `at`: `System.monotonic_time/0` when it was
  held), and they are no longer held. Called on `{:blackboard_held,
  ref}`, or at any time (a subscriber that stops takes what is left).
  [] for nothing held, or a subscription that is not the caller's or not
  batched.
  """
  @spec take_held(reference()) :: [{term(), integer()}]
  def take_held(ref) when is_reference(ref), do: Batches.take(ref)

  @doc "How many tuples were dropped for a subscription (nil if it is gone)."
  @spec dropped(reference()) :: non_neg_integer() | nil
  def dropped(ref) when is_reference(ref), do: Subscriptions.dropped(ref)

  @doc "This node's subscriptions."
  @spec subscriptions() :: [map()]
  def subscriptions, do: Subscriptions.list()

  @doc "This node's blocked `rd`/`take` requests, oldest first."
  @spec waiters() :: [map()]
  def waiters, do: Waiters.list() |> Enum.sort_by(& &1.seq)

  ## Option checking

  defp out_options([]), do: {nil, nil}

  defp out_options(opts) do
    Enum.reduce(opts, {nil, nil}, fn
      {:key, key}, {_, ttl} ->
        {key, ttl}

      {:ttl, ttl}, {key, _} when is_integer(ttl) and ttl > 0 ->
        {key, ttl}

      {:ttl, ttl}, _ ->
        raise ArgumentError,
              "out/2 option :ttl must be a positive integer of milliseconds, got: #{inspect(ttl)}"

      other, _ ->
        raise ArgumentError,
              "unknown out/2 option #{inspect(other)}; known options are :key and :ttl"
    end)
  end

  defp subscribe_options(opts) do
    unless is_list(opts),
      do:
        raise(ArgumentError, "subscribe/2 options must be a keyword list, got: #{inspect(opts)}")

    defaults = %{
      max_queue: @default_max_queue,
      on_overflow: :drop,
      batch: false,
      max_batch: nil,
      max_delay_ms: nil,
      hold: nil
    }

    o =
      Enum.reduce(opts, defaults, fn
        {:max_queue, n}, o when is_integer(n) and n > 0 ->
          %{o | max_queue: n}

        {:on_overflow, policy}, o when policy in [:drop, :disconnect] ->
          %{o | on_overflow: policy}

        {:batch, batch}, o when is_boolean(batch) ->
          %{o | batch: batch}

        {key, n}, o when key in [:max_batch, :max_delay_ms] and is_integer(n) and n > 0 ->
          Map.put(o, key, n)

        {:hold, {m, f} = hold}, o when is_atom(m) and is_atom(f) ->
          %{o | hold: hold}

        other, _ ->
          raise ArgumentError,
                "bad subscribe/2 option #{inspect(other)}; expected max_queue: positive integer, " <>
                  "on_overflow: :drop | :disconnect, batch: boolean, " <>
                  "max_batch: positive integer, max_delay_ms: positive integer, " <>
                  "hold: {module, function}"
      end)

    batch =
      cond do
        o.batch ->
          {o.max_batch || @default_max_batch, o.max_delay_ms || @default_max_delay_ms, o.hold}

        o.max_batch || o.max_delay_ms || o.hold ->
          raise ArgumentError,
                "subscribe/2 options :max_batch, :max_delay_ms and :hold need batch: true, got: " <>
                  inspect(opts)

        true ->
          nil
      end

    {o.max_queue, o.on_overflow, batch}
  end

  defp check_timeout(:infinity), do: :infinity
  defp check_timeout(ms) when is_integer(ms) and ms >= 0, do: ms

  defp check_timeout(other) do
    raise ArgumentError,
          "a blackboard timeout is a non-negative integer of milliseconds or :infinity, got: #{inspect(other)}"
  end
end
