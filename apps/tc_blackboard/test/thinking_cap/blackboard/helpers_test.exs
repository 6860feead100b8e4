defmodule ThinkingCap.Blackboard.HelpersTest do
  use ThinkingCap.BlackboardCase, async: true

  import ExUnit.CaptureIO
  import ThinkingCap.Blackboard.IEx

  describe "IEx helpers" do
    test "bb_ls prints matching tuples and returns their count", %{id: id} do
      for n <- 1..3, do: Blackboard.out({:iex, id, n})
      out = capture_io(fn -> assert bb_ls({:iex, id, :_}) == 3 end)
      assert out =~ "{:iex, #{inspect(id)}, 1}"
      assert out =~ "{:iex, #{inspect(id)}, 3}"

      out = capture_io(fn -> assert bb_ls({:iex, id, :_}, 2) == 3 end)
      assert out =~ "... 1 more"
    end

    test "bb_count counts tuples by tag and arity", %{id: id} do
      tag = :"count_#{System.unique_integer([:positive])}"
      for n <- 1..4, do: Blackboard.out({tag, id, n})
      Blackboard.out({tag, id})
      counts = bb_count()
      assert counts[{tag, 3}] == 4
      assert counts[{tag, 2}] == 1
    end

    test "bb_subscriptions and bb_waiters list this node's", %{id: id} do
      {:ok, ref} = Blackboard.subscribe({:watch, id, :_}, max_queue: 5)

      assert %{template: {:watch, ^id, :_}, max_queue: 5, dropped: 0} =
               Enum.find(bb_subscriptions(), &(&1.ref == ref))

      task = Task.async(fn -> Blackboard.rd({:waiting, id}) end)

      ThinkingCap.Testing.Cluster.wait_until(fn ->
        Enum.any?(bb_waiters(), &(&1.template == {:waiting, id}))
      end)

      Blackboard.out({:waiting, id})
      Task.await(task)
    end

    test "bb_peers is empty on a lone node" do
      assert bb_peers() == []
    end
  end

  describe "assertions" do
    test "assert_tuple returns the tuple, or fails naming what is there", %{id: id} do
      Blackboard.out({:a, id, 1})
      assert {:a, ^id, 1} = assert_tuple({:a, id, :_})

      error = assert_raise ExUnit.AssertionError, fn -> assert_tuple({:a, id, 2}, 10) end
      assert error.message =~ "no tuple matching {:a, #{inspect(id)}, 2}"
      assert error.message =~ "{:a, #{inspect(id)}, 1}"
    end

    test "refute_tuple fails when a match appears within the time", %{id: id} do
      assert :ok = refute_tuple({:b, id}, 10)
      spawn(fn -> Blackboard.out({:b, id}) end)

      assert_raise ExUnit.AssertionError, ~r/expected no tuple/, fn ->
        refute_tuple({:b, id}, 1000)
      end
    end

    test "assert_delivered waits for a matching delivery", %{id: id} do
      {:ok, ref} = Blackboard.subscribe({:c, id, :_})
      Blackboard.out({:c, id, :skip})
      Blackboard.out({:c, id, :want})
      assert {:c, ^id, :want} = assert_delivered(ref, {:c, id, :want})
      assert_raise ExUnit.AssertionError, fn -> assert_delivered(ref, {:c, id, :never}, 10) end
    end
  end
end
