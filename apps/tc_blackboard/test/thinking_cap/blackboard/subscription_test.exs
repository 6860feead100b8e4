defmodule ThinkingCap.Blackboard.SubscriptionTest do
  use ThinkingCap.BlackboardCase, async: true

  alias ThinkingCap.Testing.Cluster

  test "every later matching out is delivered, in the writer's order", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:scan, id, :_})
    for n <- 1..100, do: Blackboard.out({:scan, id, n})
    Blackboard.out({:other, id, 0})
    for n <- 1..100, do: assert_receive({:blackboard, ^ref, {:scan, ^id, ^n}})
    refute_received {:blackboard, ^ref, _}
  end

  test "positions past the indexed ones still select", %{id: id} do
    {:ok, stream} = Blackboard.subscribe({:pose, id, :_, :fine})
    {:ok, tag} = Blackboard.subscribe({:pose, :_, 2, :_})
    {:ok, exact} = Blackboard.subscribe({:pose, id, 1.0, :fine})

    Blackboard.out({:pose, id, 1, :coarse})
    Blackboard.out({:pose, id, 1, :fine})
    Blackboard.out({:pose, id, 2, :fine})

    assert_receive {:blackboard, ^stream, {:pose, ^id, 1, :fine}}
    assert_receive {:blackboard, ^stream, {:pose, ^id, 2, :fine}}
    assert_receive {:blackboard, ^tag, {:pose, ^id, 2, :fine}}
    refute_received {:blackboard, ^stream, {:pose, ^id, 1, :coarse}}
    refute_received {:blackboard, ^tag, {:pose, ^id, 1, _}}
    # positions compare exactly: 1 is not 1.0
    refute_received {:blackboard, ^exact, _}
  end

  test "tuples written before subscribing are not delivered", %{id: id} do
    Blackboard.out({:early, id})
    {:ok, ref} = Blackboard.subscribe({:early, id})
    refute_received {:blackboard, ^ref, _}
  end

  test "tag-only subscriptions of two tags sharing a flag bucket each get only their own" do
    alias ThinkingCap.Blackboard.Core.Tables
    # two new tags whose tag-only subscriptions share a flag bucket
    {a, b} = ThinkingCap.Test.Buckets.two_tags_in_a_free_bucket(:bucket)
    assert Tables.tag_bucket(3, a) == Tables.tag_bucket(3, b)

    {:ok, on_a} = Blackboard.subscribe({a, :_, :_})
    Blackboard.out({b, 1, 1})
    Blackboard.out({a, 1, 2})
    assert_receive {:blackboard, ^on_a, {^a, 1, 2}}
    refute_received {:blackboard, ^on_a, {^b, _, _}}

    {:ok, on_b} = Blackboard.subscribe({b, :_, :_})
    :ok = Blackboard.unsubscribe(on_a)
    Blackboard.out({a, 1, 3})
    Blackboard.out({b, 1, 4})
    assert_receive {:blackboard, ^on_b, {^b, 1, 4}}
    refute_received {:blackboard, _, {^a, 1, 3}}
  end

  test "wildcard-first and match-spec subscriptions are delivered too", %{id: id} do
    {:ok, any} = Blackboard.subscribe({:_, id, :_})
    {:ok, spec} = Blackboard.subscribe({:spec, [{{:temp, id, :"$1"}, [{:>, :"$1", 50}], [true]}]})
    Blackboard.out({:temp, id, 20})
    Blackboard.out({:temp, id, 80})
    assert_receive {:blackboard, ^any, {:temp, ^id, 20}}
    assert_receive {:blackboard, ^any, {:temp, ^id, 80}}
    assert_receive {:blackboard, ^spec, {:temp, ^id, 80}}
    refute_received {:blackboard, ^spec, {:temp, ^id, 20}}
  end

  test "unsubscribe stops delivery and flushes pending messages", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:u, id})
    Blackboard.out({:u, id})
    :ok = Blackboard.unsubscribe(ref)
    refute_received {:blackboard, ^ref, _}
    Blackboard.out({:u, id})
    refute_received {:blackboard, ^ref, _}
    assert Blackboard.dropped(ref) == nil
  end

  test "a subscriber that dies is cleaned up", %{id: id} do
    parent = self()

    pid =
      spawn(fn ->
        {:ok, ref} = Blackboard.subscribe({:d, id})
        send(parent, {:subscribed, ref})
        Process.sleep(:infinity)
      end)

    assert_receive {:subscribed, ref}
    assert Enum.any?(Blackboard.subscriptions(), &(&1.ref == ref and &1.pid == pid))
    Process.exit(pid, :kill)
    Cluster.wait_until(fn -> not Enum.any?(Blackboard.subscriptions(), &(&1.ref == ref)) end)
  end

  describe "a slow subscriber cannot stall writers" do
    test ":drop keeps at most max_queue messages queued and counts the rest", %{id: id} do
      {slow, ref} = stalled_subscriber({:flood, id, :_}, max_queue: 10)
      {:ok, fast} = Blackboard.subscribe({:flood, id, :_})

      for n <- 1..1000, do: :ok = Blackboard.out({:flood, id, n})

      assert {:message_queue_len, 10} = Process.info(slow, :message_queue_len)
      assert Blackboard.dropped(ref) == 990
      # other subscribers still get everything
      for n <- 1..1000, do: assert_received({:blackboard, ^fast, {:flood, ^id, ^n}})
      # the first ten are the ones kept
      assert {:messages, kept} = Process.info(slow, :messages)
      assert Enum.map(kept, fn {:blackboard, _, {:flood, _, n}} -> n end) == Enum.to_list(1..10)
    end

    test ":drop holds the bound with a large max_queue and writers racing", %{id: id} do
      {slow, ref} = stalled_subscriber({:flood, id, :_}, max_queue: 1_000)

      1..4
      |> Enum.map(fn w ->
        Task.async(fn -> for n <- 1..20_000, do: :ok = Blackboard.out({:flood, id, {w, n}}) end)
      end)
      |> Enum.each(&Task.await(&1, 60_000))

      # read every 1000/64 = 15 tuples (after the send), and before every
      # one while full: at most 15 more, and one, per racing writer
      assert {:message_queue_len, queued} = Process.info(slow, :message_queue_len)
      assert queued >= 1_000 and queued <= 1_000 + 4 * (15 + 1)
      assert Blackboard.dropped(ref) == 80_000 - queued
    end

    test ":disconnect with a large max_queue cuts off within 1/64 of it", %{id: id} do
      {slow, ref} = stalled_subscriber({:flood, id, :_}, max_queue: 200, on_overflow: :disconnect)

      for n <- 1..1000, do: :ok = Blackboard.out({:flood, id, n})

      # read every 200/64 = 3 tuples, after the send: cut off at the first
      # read that finds 200 or more
      assert {:messages, messages} = Process.info(slow, :messages)
      assert List.last(messages) == {:blackboard_overflow, ref}
      assert (length(messages) - 1) in 200..(200 + 3 + 1)
      refute Enum.any?(Blackboard.subscriptions(), &(&1.ref == ref))
    end

    test ":disconnect unsubscribes the subscriber and tells it", %{id: id} do
      {slow, ref} = stalled_subscriber({:flood, id, :_}, max_queue: 5, on_overflow: :disconnect)
      for n <- 1..50, do: :ok = Blackboard.out({:flood, id, n})

      assert {:messages, messages} = Process.info(slow, :messages)
      assert length(messages) == 6
      assert List.last(messages) == {:blackboard_overflow, ref}
      refute Enum.any?(Blackboard.subscriptions(), &(&1.ref == ref))
    end
  end

  # A process that subscribes, then stops reading its mailbox.
  defp stalled_subscriber(template, opts) do
    parent = self()

    pid =
      spawn_link(fn ->
        {:ok, ref} = Blackboard.subscribe(template, opts)
        send(parent, {:ref, ref})
        receive do: (:never -> :ok)
      end)

    assert_receive {:ref, ref}
    {pid, ref}
  end
end
