defmodule ThinkingCap.Blackboard.StagingTest do
  # A write that wakes local subscribers is staged (in the fresh table)
  # before they are sent it and settled (copied into the tuple table) after
  # the writer yielded to them. These tests stop writes between the two
  # halves, as a writer killed there would.
  use ThinkingCap.BlackboardCase, async: true

  alias ThinkingCap.Blackboard.Core.{Store, Tables}

  defp stored(id),
    do:
      :ets.select(Tables.tuples(), [{{{3, :staged, id, :_, :_}, :"$1", :_, :_, :_}, [], [:"$1"]}])

  defp staged(id),
    do:
      :ets.select(Tables.fresh(), [
        {{{3, :staged, id, :_, :_}, :"$1", :_, :_, :_, :_}, [], [:"$1"]}
      ])

  test "a staged write is read and listed before it is settled, and taken once settled",
       %{id: id} do
    Blackboard.out({:staged, id, 1})
    record = Store.new_record({:staged, id, 2}, nil, nil)
    Store.stage(record)

    assert [{:staged, ^id, 2}] = staged(id)
    assert [{:staged, ^id, 1}, {:staged, ^id, 2}] = Blackboard.rd_all({:staged, id, :_})
    assert [{:staged, ^id, 2}] = Blackboard.rd_all({:staged, :_, 2})
    assert {:ok, {:staged, ^id, 2}} = Blackboard.rdp({:_, id, 2})
    assert {:ok, {:staged, ^id, 2}} = Blackboard.rdp({:staged, id, 2})
    assert {:ok, {:staged, ^id, 1}} = Blackboard.takep({:staged, id, :_})

    # the take of a staged tuple waits until it is settled
    me = self()
    taker = spawn_link(fn -> send(me, {:took, Blackboard.takep({:staged, id, :_})}) end)
    refute_receive {:took, _}, 50
    assert Process.alive?(taker)
    Store.settle(record)
    assert_receive {:took, {:ok, {:staged, ^id, 2}}}

    assert stored(id) == []
    assert staged(id) == []
  end

  test "a high-priority taker waits for a staged tuple and keeps its priority", %{id: id} do
    record = Store.new_record({:staged, id, :urgent}, nil, nil)
    Store.stage(record)
    me = self()

    spawn_link(fn ->
      Process.flag(:priority, :high)
      taken = Blackboard.takep({:staged, id, :_})
      send(me, {:took, taken, Process.info(self(), :priority)})
    end)

    refute_receive {:took, _, _}, 50
    Store.settle(record)
    assert_receive {:took, {:ok, {:staged, ^id, :urgent}}, {:priority, :high}}
  end

  test "a staged keyed write replaces the older tuple when it is settled", %{id: id} do
    Blackboard.out({:staged, id, :old}, key: {:staged, id})
    record = Store.new_record({:staged, id, :new}, {:staged, id}, nil)
    Store.stage(record)

    # for an instant both, never neither
    assert length(Blackboard.rd_all({:staged, id, :_})) == 2
    Store.settle(record)
    assert [{:staged, ^id, :new}] = Blackboard.rd_all({:staged, id, :_})
    assert [{:staged, ^id, :new}] = stored(id)
    assert staged(id) == []
  end

  test "the sweeper settles what a killed writer left staged, and nothing else", %{id: id} do
    me = self()

    writer = fn tuple, copied? ->
      spawn(fn ->
        record = Store.new_record(tuple, nil, nil)
        Store.stage(record)
        # killed after copying, before dropping its fresh row
        if copied?, do: :ets.insert(Tables.tuples(), record)
        send(me, :staged)
        Process.sleep(:infinity)
      end)
    end

    before_copy = writer.({:staged, id, :before_copy}, false)
    after_copy = writer.({:staged, id, :after_copy}, true)
    alive = writer.({:staged, id, :alive}, false)
    for _ <- 1..3, do: assert_receive(:staged)
    Process.exit(before_copy, :kill)
    Process.exit(after_copy, :kill)

    # sweeps run every 500 ms
    ThinkingCap.Testing.Cluster.wait_until(fn -> staged(id) == [{:staged, id, :alive}] end, 5_000)
    assert Enum.sort(stored(id)) == [{:staged, id, :after_copy}, {:staged, id, :before_copy}]
    assert length(Blackboard.rd_all({:staged, id, :_})) == 3

    # taken once each, the live writer's only once it settles
    assert {:ok, _} = Blackboard.takep({:staged, id, :before_copy})
    assert {:ok, _} = Blackboard.takep({:staged, id, :after_copy})
    assert :none = Blackboard.takep({:staged, id, :before_copy})
    assert :none = Blackboard.takep({:staged, id, :after_copy})
    Process.exit(alive, :kill)
    assert {:ok, {:staged, ^id, :alive}} = Blackboard.takep({:staged, id, :alive})
  end

  test "a keyed writer killed after its copy, before its claim, still replaces the older tuple",
       %{id: id} do
    me = self()
    Blackboard.out({:staged, id, :old}, key: {:staged, id})

    writer =
      spawn(fn ->
        record = Store.new_record({:staged, id, :new}, {:staged, id}, nil)
        Store.stage(record)
        :ets.insert(Tables.tuples(), record)
        send(me, :copied)
        Process.sleep(:infinity)
      end)

    assert_receive :copied
    Process.exit(writer, :kill)

    # until the sweeper comes, the latest value and its predecessor; after
    # it, the latest value alone, stored once
    ThinkingCap.Testing.Cluster.wait_until(fn -> staged(id) == [] end, 5_000)
    assert [{:staged, ^id, :new}] = Blackboard.rd_all({:staged, id, :_})
    assert [{:staged, ^id, :new}] = stored(id)

    # and the key is the new tuple's: the next write replaces it
    Blackboard.out({:staged, id, :newer}, key: {:staged, id})
    assert [{:staged, ^id, :newer}] = Blackboard.rd_all({:staged, id, :_})
  end

  test "a keyed write nobody is sent is staged too, and settled before out returns",
       %{id: id} do
    :ok = Blackboard.out({:staged, id, :first}, key: {:staged, id})
    :ok = Blackboard.out({:staged, id, :second}, key: {:staged, id})
    assert [{:staged, ^id, :second}] = stored(id)
    assert staged(id) == []
  end

  test "a write that wakes a subscriber is settled before out returns", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:staged, id, :_})
    :ok = Blackboard.out({:staged, id, :heard})
    assert_receive {:blackboard, ^ref, {:staged, ^id, :heard}}
    assert [{:staged, ^id, :heard}] = stored(id)
    assert staged(id) == []
  end

  test "subscribers take the tuples they are sent, from any scheduler", %{id: id} do
    me = self()

    for n <- 1..4 do
      spawn_link(fn ->
        {:ok, ref} = Blackboard.subscribe({:staged, id, n})
        send(me, {:ready, n})

        for _ <- 1..200 do
          receive do
            {:blackboard, ^ref, tuple} -> send(me, {:took, n, Blackboard.takep(tuple)})
          end
        end
      end)
    end

    for n <- 1..4, do: assert_receive({:ready, ^n})

    1..4
    |> Enum.map(fn n ->
      Task.async(fn -> for _ <- 1..200, do: Blackboard.out({:staged, id, n}) end)
    end)
    |> Enum.each(&Task.await/1)

    for _ <- 1..800 do
      assert_receive {:took, _n, {:ok, {:staged, ^id, _}}}, 5_000
    end

    assert Blackboard.rd_all({:staged, id, :_}) == []
  end
end
