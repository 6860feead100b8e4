defmodule ThinkingCap.Blackboard.StagingTest do
  # A write that wakes subscribers is staged before they are sent it and
  # settled (indexed) after the writer yielded to them. These tests stop a
  # write between the two halves, as a writer killed there would.
  use ThinkingCap.BlackboardCase, async: true

  alias ThinkingCap.Blackboard.Core.{Store, Tables}

  defp index_keys(id),
    do: :ets.select(Tables.index(), [{{{3, :staged, id, :_, :_}}, [], [:"$_"]}])

  defp fresh_keys(id),
    do: :ets.select(Tables.fresh(), [{{{3, :staged, id, :_, :_}}, [], [:"$_"]}])

  test "a staged write is read, listed and taken before it is settled", %{id: id} do
    Blackboard.out({:staged, id, 1})
    record = Store.new_record({:staged, id, 2}, nil, nil)
    Store.stage(record)

    assert index_keys(id) |> length() == 1
    assert [{:staged, ^id, 1}, {:staged, ^id, 2}] = Blackboard.rd_all({:staged, id, :_})
    assert [{:staged, ^id, 2}] = Blackboard.rd_all({:staged, :_, 2})
    assert {:ok, {:staged, ^id, 1}} = Blackboard.takep({:staged, id, :_})
    assert {:ok, {:staged, ^id, 2}} = Blackboard.rdp({:_, id, 2})
    assert {:ok, {:staged, ^id, 2}} = Blackboard.takep({:staged, id, :_})

    # settling a write that was taken meanwhile leaves no index entry behind
    Store.settle(record)
    assert index_keys(id) == []
    assert fresh_keys(id) == []
    assert Blackboard.rd_all({:staged, id, :_}) == []
  end

  test "a staged keyed write replaces the older tuple when it is settled", %{id: id} do
    Blackboard.out({:staged, id, :old}, key: {:staged, id})
    record = Store.new_record({:staged, id, :new}, {:staged, id}, nil)
    Store.stage(record)

    # for an instant both, never neither
    assert length(Blackboard.rd_all({:staged, id, :_})) == 2
    Store.settle(record)
    assert [{:staged, ^id, :new}] = Blackboard.rd_all({:staged, id, :_})
    assert [{{3, :staged, ^id, _, _}}] = index_keys(id)

    # settling twice (a sweep racing the writer) changes nothing
    Store.settle(record)
    assert [{:staged, ^id, :new}] = Blackboard.rd_all({:staged, id, :_})
  end

  test "the sweeper settles a write its killed writer left staged", %{id: id} do
    Store.stage(Store.new_record({:staged, id, :orphan}, nil, nil))
    assert [_] = fresh_keys(id)
    assert index_keys(id) == []

    # settled on the second sweep that sees it (sweeps run every 500 ms)
    ThinkingCap.Testing.Cluster.wait_until(fn -> fresh_keys(id) == [] end, 5_000)
    assert [_] = index_keys(id)
    assert {:ok, {:staged, ^id, :orphan}} = Blackboard.takep({:staged, id, :_})
    assert index_keys(id) == []
  end

  test "a write that wakes a subscriber is settled before out returns", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:staged, id, :_})
    :ok = Blackboard.out({:staged, id, :heard})
    assert_receive {:blackboard, ^ref, {:staged, ^id, :heard}}
    assert [_] = index_keys(id)
    assert fresh_keys(id) == []
  end

  test "a subscriber takes the tuple it was sent, from any scheduler", %{id: id} do
    me = self()

    takers =
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

    writers =
      for n <- 1..4,
          do: Task.async(fn -> for _ <- 1..200, do: Blackboard.out({:staged, id, n}) end)

    Enum.each(writers, &Task.await/1)

    results =
      for _ <- 1..800 do
        assert_receive {:took, _n, result}, 5_000
        result
      end

    assert Enum.all?(results, &match?({:ok, _}, &1))
    assert length(takers) == 4
  end
end
