defmodule ThinkingCap.BlackboardTest do
  use ThinkingCap.BlackboardCase, async: true

  alias ThinkingCap.Blackboard.Core.Server

  describe "out, rdp, rd_all, takep" do
    test "a written tuple can be read any number of times and taken once", %{id: id} do
      :ok = Blackboard.out({:job, id, %{n: 1}})
      assert {:ok, {:job, ^id, %{n: 1}}} = Blackboard.rdp({:job, id, :_})
      assert {:ok, {:job, ^id, %{n: 1}}} = Blackboard.rdp({:job, id, %{n: 1}})
      assert {:ok, {:job, ^id, %{n: 1}}} = Blackboard.takep({:job, id, :_})
      assert :none = Blackboard.takep({:job, id, :_})
      assert :none = Blackboard.rdp({:job, id, :_})
    end

    test "wildcards select by position and values must be equal, not just ==", %{id: id} do
      Blackboard.out({:v, id, 1})
      Blackboard.out({:v, id, 1.0})
      Blackboard.out({:v, id, :other})
      assert [{:v, ^id, 1}] = Blackboard.rd_all({:v, id, 1})
      assert [{:v, ^id, 1.0}] = Blackboard.rd_all({:v, id, 1.0})
      assert length(Blackboard.rd_all({:v, id, :_})) == 3
      assert [] = Blackboard.rd_all({:v, id, :_, :_})
    end

    test "a stream's robot id is matched exactly: 1 is not 1.0, though they sort together",
         %{id: id} do
      tag = :"exact_#{System.unique_integer([:positive])}"
      Blackboard.out({tag, 1.0, :a})
      Blackboard.out({tag, 1, :b})
      Blackboard.out({tag, 1.0, :c})
      Blackboard.out({tag, 2, :d, id})

      assert {:ok, {^tag, 1, :b}} = Blackboard.rdp({tag, 1, :_})
      assert {:ok, {^tag, 1.0, :a}} = Blackboard.rdp({tag, 1.0, :_})
      assert {:ok, {^tag, 1.0, :a}} = Blackboard.takep({tag, 1.0, :_})
      assert {:ok, {^tag, 1.0, :c}} = Blackboard.takep({tag, 1.0, :_})
      assert :none = Blackboard.takep({tag, 1.0, :_})
      assert {:ok, {^tag, 1, :b}} = Blackboard.takep({tag, 1, :_})
      assert :none = Blackboard.rdp({tag, 1, :_})
      # another arity is another stream
      assert :none = Blackboard.rdp({tag, 2, :_})
      assert {:ok, {^tag, 2, :d, ^id}} = Blackboard.rdp({tag, 2, :_, :_})
    end

    test "takes go on past a stream's first batches of matching tuples taken meanwhile",
         %{id: id} do
      for i <- 1..20, do: Blackboard.out({:batch, id, :skip, i})
      for i <- 1..40, do: Blackboard.out({:batch, id, :take, i})
      takes = for _ <- 1..40, do: Blackboard.takep({:batch, id, :take, :_})
      assert takes == for(i <- 1..40, do: {:ok, {:batch, id, :take, i}})
      assert :none = Blackboard.takep({:batch, id, :take, :_})
      assert length(Blackboard.rd_all({:batch, id, :skip, :_})) == 20
    end

    test "concurrent takers of one stream take every tuple exactly once", %{id: id} do
      for i <- 1..3000, do: Blackboard.out({:jobs, id, i})

      taken =
        1..8
        |> Enum.map(fn _ ->
          Task.async(fn ->
            Stream.repeatedly(fn -> Blackboard.takep({:jobs, id, :_}) end)
            |> Enum.take_while(&(&1 != :none))
            |> Enum.map(fn {:ok, {:jobs, _, i}} -> i end)
          end)
        end)
        |> Enum.flat_map(&Task.await(&1, 30_000))

      assert Enum.sort(taken) == Enum.to_list(1..3000)
    end

    test "tuples of one tag are read and taken oldest first", %{id: id} do
      for n <- 1..5, do: Blackboard.out({:seq, id, n})
      assert {:ok, {:seq, ^id, 1}} = Blackboard.rdp({:seq, id, :_})

      assert Enum.map(1..5, fn _ -> Blackboard.takep({:seq, id, :_}) end) ==
               Enum.map(1..5, &{:ok, {:seq, id, &1}})
    end

    test "a match-spec template selects with guards", %{id: id} do
      for n <- 1..10, do: Blackboard.out({:reading, id, n})
      spec = {:spec, [{{:reading, id, :"$1"}, [{:>, :"$1", 7}], [true]}]}

      assert Enum.sort(Blackboard.rd_all(spec)) == [
               {:reading, id, 8},
               {:reading, id, 9},
               {:reading, id, 10}
             ]

      assert {:ok, {:reading, ^id, 8}} = Blackboard.takep(spec)
      assert length(Blackboard.rd_all({:reading, id, :_})) == 9
    end

    test "the empty tuple and one-element tuples work", %{id: _} do
      Blackboard.out({})
      assert {:ok, {}} = Blackboard.takep({})
      Blackboard.out({:lonely})
      assert {:ok, {:lonely}} = Blackboard.takep({:lonely})
    end
  end

  describe "latest-value keys" do
    test "a keyed write replaces the previous tuple with that key only", %{id: id} do
      Blackboard.out({:pose, id, %{x: 0}}, key: {:pose, id})
      Blackboard.out({:pose, id, %{x: 1}}, key: {:pose, id})
      Blackboard.out({:pose, id, %{x: 2}}, key: {:pose, id})
      Blackboard.out({:pose, id, %{x: 99}})

      assert Enum.sort(Blackboard.rd_all({:pose, id, :_})) == [
               {:pose, id, %{x: 2}},
               {:pose, id, %{x: 99}}
             ]
    end

    test "concurrent writers of one key leave exactly one tuple", %{id: id} do
      key = {:stream, id}

      1..8
      |> Enum.map(fn w ->
        Task.async(fn -> for i <- 1..200, do: Blackboard.out({:stream, id, {w, i}}, key: key) end)
      end)
      |> Enum.each(&Task.await/1)

      assert [{:stream, ^id, {_w, 200}}] = Blackboard.rd_all({:stream, id, :_})
    end

    test "writers racing on one key while a taker takes it leave no stray tuple or index entry",
         %{id: id} do
      alias ThinkingCap.Blackboard.Core.Tables
      key = {:race, id}
      parent = self()

      taker =
        spawn_link(fn ->
          taken = Stream.repeatedly(fn -> Blackboard.takep({:race, id, :_}) end)
          send(parent, {:taken, Enum.count(Stream.take_while(taken, fn _ -> not stop?() end))})
        end)

      1..8
      |> Enum.map(fn w ->
        Task.async(fn -> for i <- 1..2000, do: Blackboard.out({:race, id, {w, i}}, key: key) end)
      end)
      |> Enum.each(&Task.await(&1, 30_000))

      send(taker, :stop)
      assert_receive {:taken, n} when n > 0, 5000
      assert length(Blackboard.rd_all({:race, id, :_})) <= 1

      # the next write is the one tuple, and the index holds it alone
      Blackboard.out({:race, id, :last}, key: key)
      assert [{:race, ^id, :last}] = Blackboard.rd_all({:race, id, :_})
      assert [{_, record_key, _}] = :ets.lookup(Tables.keys(), :erlang.term_to_binary(key))

      assert [{^record_key, {:race, ^id, :last}, _, _, _}] =
               :ets.lookup(Tables.tuples(), record_key)
    end

    test "taking a keyed tuple lets the key be written again", %{id: id} do
      Blackboard.out({:k, id, 1}, key: id)
      assert {:ok, _} = Blackboard.takep({:k, id, :_})
      Blackboard.out({:k, id, 2}, key: id)
      assert [{:k, ^id, 2}] = Blackboard.rd_all({:k, id, :_})
    end
  end

  describe "time to live" do
    test "an expired tuple is never returned and is removed", %{id: id} do
      Blackboard.out({:ttl, id, :short}, ttl: 30)
      Blackboard.out({:ttl, id, :long}, ttl: 600_000)

      ThinkingCap.Testing.Cluster.wait_until(fn ->
        Blackboard.rd_all({:ttl, id, :_}) == [{:ttl, id, :long}]
      end)

      assert :none = Blackboard.takep({:ttl, id, :short})

      # the sweeper deletes the record itself, not just hides it
      ThinkingCap.Testing.Cluster.wait_until(fn ->
        :ets.select_count(:tc_bb_tuples, [{{:_, {:ttl, id, :short}, :_, :_, :_}, [], [true]}]) ==
          0
      end)
    end
  end

  # Writes {tag, id, k} for each k in turn: taker k is served it, nobody else.
  defp assert_served_in_order(tag, id, ks) do
    for k <- ks do
      Blackboard.out({tag, id, k})
      assert_receive {:served, ^k, {:ok, {^tag, ^id, _}}}, 2000
      refute_received {:served, _, _}
    end
  end

  describe "blocking rd and take" do
    test "a blocked rd wakes on a later out and leaves the tuple", %{id: id} do
      task = Task.async(fn -> Blackboard.rd({:later, id, :_}) end)
      wait_for_waiters(id, 1)
      Blackboard.out({:later, id, 1})
      assert {:ok, {:later, ^id, 1}} = Task.await(task)
      assert {:ok, _} = Blackboard.rdp({:later, id, :_})
    end

    test "a blocked take wakes on a later out and removes the tuple", %{id: id} do
      task = Task.async(fn -> Blackboard.take({:later, id, :_}) end)
      wait_for_waiters(id, 1)
      Blackboard.out({:later, id, 1})
      assert {:ok, {:later, ^id, 1}} = Task.await(task)
      assert :none = Blackboard.rdp({:later, id, :_})
    end

    test "every blocked rd sees the tuple, one blocked take gets it", %{id: id} do
      readers = for _ <- 1..3, do: Task.async(fn -> Blackboard.rd({:one, id}) end)
      taker = Task.async(fn -> Blackboard.take({:one, id}) end)
      wait_for_waiters(id, 4)
      Blackboard.out({:one, id})
      assert Enum.map([taker | readers], &Task.await/1) == List.duplicate({:ok, {:one, id}}, 4)
    end

    test "blocked readers see a tuple even when a blocked taker takes it first", %{id: id} do
      readers = for _ <- 1..3, do: Task.async(fn -> Blackboard.rd({:raced, id}, 5000) end)
      wait_for_waiters(id, 3)
      taker = Task.async(fn -> Blackboard.take({:raced, id}, 5000) end)
      wait_for_waiters(id, 4)

      # the readers cannot act on their wake-up before the taker has taken
      Enum.each(readers, &:erlang.suspend_process(&1.pid))
      Blackboard.out({:raced, id})
      assert {:ok, {:raced, ^id}} = Task.await(taker)
      assert :none = Blackboard.rdp({:raced, id})
      Enum.each(readers, &:erlang.resume_process(&1.pid))

      assert Enum.map(readers, &Task.await/1) == List.duplicate({:ok, {:raced, id}}, 3)
    end

    test "blocked takers of one template are served in arrival order", %{id: id} do
      parent = self()

      for n <- 1..4 do
        spawn_link(fn -> send(parent, {:served, n, Blackboard.take({:fifo, id, :_})}) end)
        wait_for_waiters(id, n)
      end

      # the server has heard of every taker before the first tuple arrives
      # (a taker it hears of after a tuple: the next test)
      :sys.get_state(Server)

      assert_served_in_order(:fifo, id, 1..4)
    end

    test "a taker whose arrival the server hears of after a tuple's does not go first",
         %{id: id} do
      parent = self()

      taker = fn n ->
        spawn_link(fn -> send(parent, {:served, n, Blackboard.take({:late, id, :_})}) end)
      end

      [first | _] =
        for n <- 1..3 do
          pid = taker.(n)
          wait_for_waiters(id, n)
          pid
        end

      # the server has seen takers 1..3; it hears of taker 4 only after the
      # tuple has arrived
      :sys.get_state(Server)
      :sys.suspend(Server)
      taker.(4)
      wait_for_waiters(id, 4)
      Blackboard.out({:late, id, 1})

      # The late taker's kick finds the tuple and wakes the oldest taker;
      # the arrival after it finds that taker on its way to the only tuple
      # and wakes nobody to race it: with taker 1 held, nobody is served.
      :erlang.suspend_process(first)
      :sys.resume(Server)
      :sys.get_state(Server)
      refute_receive {:served, _, _}, 100
      :erlang.resume_process(first)
      assert_receive {:served, 1, {:ok, {:late, ^id, 1}}}, 2000

      assert_served_in_order(:late, id, 2..4)
    end

    test "a woken taker beaten to its tuple by a takep waits again, ahead of later takers",
         %{id: id} do
      parent = self()

      takers =
        for n <- 1..2 do
          pid =
            spawn_link(fn -> send(parent, {:served, n, Blackboard.take({:beaten, id, :_})}) end)

          wait_for_waiters(id, n)
          pid
        end

      # taker 1 is woken for the tuple but cannot act before a takep takes it
      :sys.get_state(Server)
      :erlang.suspend_process(hd(takers))
      Blackboard.out({:beaten, id, 1})
      :sys.get_state(Server)
      assert {:ok, {:beaten, ^id, 1}} = Blackboard.takep({:beaten, id, :_})
      :erlang.resume_process(hd(takers))
      refute_receive {:served, _, _}, 100

      # taker 1 waits again, and is still served first
      Blackboard.out({:beaten, id, 2})
      assert_receive {:served, 1, {:ok, {:beaten, ^id, 2}}}, 2000
      Blackboard.out({:beaten, id, 3})
      assert_receive {:served, 2, {:ok, {:beaten, ^id, 3}}}, 2000
    end

    test "a taker that blocks while the write it waits for is in flight is woken", %{id: id} do
      # the taker starts to block as the write starts: on two schedulers
      # the two overlap, in either order
      me = self()

      for i <- 1..300 do
        task =
          Task.async(fn ->
            send(me, :taking)
            Blackboard.take({:in_flight, id, i}, 2_000)
          end)

        assert_receive :taking
        Blackboard.out({:in_flight, id, i})
        assert {:ok, {:in_flight, ^id, ^i}} = Task.await(task)
      end
    end

    test "a timeout returns an error and leaves nothing behind", %{id: id} do
      assert {:error, :timeout} = Blackboard.take({:never, id}, 20)
      assert {:error, :timeout} = Blackboard.rd({:never, id}, 0)
      assert waiters_for(id) == []
      # the tuple written afterwards is not consumed by the gone taker
      Blackboard.out({:never, id})
      assert {:ok, {:never, ^id}} = Blackboard.takep({:never, id})
      refute_received {:tc_bb_wake, _, _}
    end

    test "a woken taker that times out passes the tuple on to the next", %{id: id} do
      # a taker that is suspended cannot act on its wake-up before it times out
      slow = spawn(fn -> Blackboard.take({:handoff, id}, 100) end)
      wait_for_waiters(id, 1)
      fast = Task.async(fn -> Blackboard.take({:handoff, id}, 5000) end)
      wait_for_waiters(id, 2)
      :erlang.suspend_process(slow)
      Blackboard.out({:handoff, id})
      Process.sleep(150)
      :erlang.resume_process(slow)
      assert {:ok, {:handoff, ^id}} = Task.await(fast)
    end

    test "a blocked waiter that dies is cleaned up", %{id: id} do
      pid = spawn(fn -> Blackboard.take({:dies, id}) end)
      wait_for_waiters(id, 1)
      Process.exit(pid, :kill)
      ThinkingCap.Testing.Cluster.wait_until(fn -> waiters_for(id) == [] end)
      Blackboard.out({:dies, id})
      assert {:ok, _} = Blackboard.takep({:dies, id})
    end
  end

  describe "bad input" do
    test "out of a non-tuple or with bad options raises ArgumentError" do
      assert_raise ArgumentError, ~r/writes tuples, got: \[:not, :a, :tuple\]/, fn ->
        Blackboard.out([:not, :a, :tuple])
      end

      assert_raise ArgumentError, ~r/:ttl must be a positive integer/, fn ->
        Blackboard.out({:a}, ttl: -1)
      end

      assert_raise ArgumentError, ~r/unknown out\/2 option \{:tll, 5\}/, fn ->
        Blackboard.out({:a}, tll: 5)
      end

      assert_raise ArgumentError, ~r/keyword list/, fn -> Blackboard.out({:a}, :oops) end
    end

    test "malformed templates and match specs raise ArgumentError" do
      assert_raise ArgumentError, ~r/must be a tuple/, fn -> Blackboard.rdp([:a]) end
      assert_raise ArgumentError, ~r/must be a tuple/, fn -> Blackboard.subscribe(:scan) end

      assert_raise ArgumentError, ~r/non-empty list of \{head, guards, body\}/, fn ->
        Blackboard.rd_all({:spec, :x})
      end

      assert_raise ArgumentError, ~r/invalid ETS match specification/, fn ->
        Blackboard.takep({:spec, [{{:a, :"$1"}, [{:no_such_guard, :"$1"}], [true]}]})
      end

      assert_raise ArgumentError, ~r/timeout/, fn -> Blackboard.rd({:a}, -5) end

      assert_raise ArgumentError, ~r/bad subscribe\/2 option/, fn ->
        Blackboard.subscribe({:a}, max_queue: 0)
      end

      assert_raise ArgumentError, ~r/0-arity function/, fn -> Blackboard.eval(fn x -> x end) end
    end
  end

  describe "eval" do
    test "the tuple a function returns is written", %{id: id} do
      assert {:ok, pid} = Blackboard.eval(fn -> {:computed, id, 6 * 7} end)
      assert is_pid(pid)
      assert {:computed, ^id, 42} = assert_tuple({:computed, id, :_})
      assert {:ok, _} = Blackboard.eval({List, :to_tuple, [[:mfa, id]]})
      assert_tuple({:mfa, id})
    end

    test "a crash or a non-tuple result is reported, not lost", %{id: id} do
      {:ok, ref} = Blackboard.subscribe({:eval_error, node(), :_})

      log =
        ExUnit.CaptureLog.capture_log(fn ->
          {:ok, _} = Blackboard.eval(fn -> raise "boom #{inspect(id)}" end)
          assert %{reason: reason} = elem(assert_delivered(ref, {:eval_error, :_, :_}), 2)
          assert reason =~ "boom"
          {:ok, _} = Blackboard.eval(fn -> :not_a_tuple end)
          assert %{reason: reason} = elem(assert_delivered(ref, {:eval_error, :_, :_}), 2)
          assert reason =~ "not a tuple"
        end)

      assert log =~ "blackboard eval of"
      assert log =~ "boom"
    end
  end

  defp waiters_for(id),
    do:
      Enum.filter(
        Blackboard.waiters(),
        &(tuple_size(&1.template) > 1 and elem(&1.template, 1) == id)
      )

  defp wait_for_waiters(id, n) do
    ThinkingCap.Testing.Cluster.wait_until(fn -> length(waiters_for(id)) >= n end)
  end

  defp stop? do
    receive do
      :stop -> true
    after
      0 -> false
    end
  end
end
