defmodule ThinkingCap.Blackboard.ClusterTest do
  @moduledoc false
  # Real nodes started with :peer; each test gets its own cluster.
  use ExUnit.Case, async: false

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Test.NodeWorkers, as: W
  alias ThinkingCap.Testing.Cluster

  @moduletag :cluster
  @moduletag timeout: 120_000

  defp start(count) do
    nodes = Cluster.start(count)
    on_exit(fn -> Cluster.stop(nodes) end)
    nodes
  end

  defp call(node, m, f, a, timeout \\ 15_000), do: Cluster.call(node, m, f, a, timeout)
  defp bb(node, f, a), do: call(node, Blackboard, f, a)

  defp eventually(fun), do: Cluster.wait_until(fun)

  test "tuples written on one node are readable, takeable and delivered on the others" do
    [a, b, c] = start(3)
    on_b = call(b, W, :collector, [{:sensor, :_, :_}])
    on_c = call(c, W, :collector, [{:sensor, :_, :_}])

    :ok = call(a, W, :write, [:sensor, 1..3])

    expected = for n <- 1..3, do: {:sensor, a.node, n}

    eventually(fn ->
      call(b, W, :ask, [on_b]) == expected and call(c, W, :ask, [on_c]) == expected
    end)

    assert bb(b, :rd_all, [{:sensor, :_, :_}]) |> Enum.sort() == expected
    assert {:ok, {:sensor, _, 1}} = bb(c, :takep, [{:sensor, :_, 1}])
    # the take is seen everywhere, the owner included
    eventually(fn -> Enum.all?([a, b, c], &(bb(&1, :rdp, [{:sensor, :_, 1}]) == :none)) end)
    assert :none = bb(b, :takep, [{:sensor, :_, 1}])
  end

  test "a take prefers this node's oldest match to another node's older one" do
    [a, b] = start(2)
    # a's writes advance its sequence far past b's: b's tuple sorts first
    :ok = call(a, W, :write, [:burn, 1..5000])

    for template <- [{:pref, :r1, :_}, {:pref, :_, :_}] do
      tag = elem(template, 0)
      :ok = bb(b, :out, [{tag, :r1, :from_b}])
      eventually(fn -> bb(a, :rdp, [{tag, :r1, :from_b}]) != :none end)
      :ok = bb(a, :out, [{tag, :r1, :from_a}])
      assert [{^tag, :r1, :from_b}, {^tag, :r1, :from_a}] = bb(a, :rd_all, [template])

      assert {:ok, {^tag, :r1, :from_a}} = bb(a, :takep, [template])
      assert {:ok, {^tag, :r1, :from_b}} = bb(a, :takep, [template])
      assert :none = bb(a, :takep, [template])
      eventually(fn -> bb(b, :rdp, [template]) == :none end)
    end
  end

  test "one writer's tuples reach every node's subscribers in the order written" do
    [a, b, c] = start(3)
    on_b = call(b, W, :collector, [{:ordered, :_, :_}])
    on_c = call(c, W, :collector, [{:ordered, :_, :_}])

    call(a, W, :write, [:ordered, 1..2000])
    expected = for n <- 1..2000, do: {:ordered, a.node, n}

    eventually(fn ->
      length(call(b, W, :ask, [on_b])) == 2000 and length(call(c, W, :ask, [on_c])) == 2000
    end)

    assert call(b, W, :ask, [on_b]) == expected
    assert call(c, W, :ask, [on_c]) == expected
  end

  test "a blocked rd and take on one node wake on an out on another" do
    [a, b] = start(2)
    reader = call(b, W, :start_blocking, [:rd, {:wake, :_}, 10_000])
    taker = call(b, W, :start_blocking, [:take, {:wake, :_}, 10_000])
    eventually(fn -> length(bb(b, :waiters, [])) == 2 end)

    bb(a, :out, [{:wake, 1}])

    assert {:ok, {:wake, 1}} = call(b, W, :ask, [reader])
    assert {:ok, {:wake, 1}} = call(b, W, :ask, [taker])
    eventually(fn -> bb(a, :rdp, [{:wake, :_}]) == :none end)
  end

  test "take is exactly-once with concurrent takers on every node" do
    nodes = start(3)
    assert_taken_once(nodes, :job, 300)
  end

  test "take stays exactly-once when every write wakes a subscriber on its node" do
    # such writes are staged and settled around a yield: takers on the
    # other nodes take them through the owner while they may be staged
    nodes = start(3)
    Enum.each(nodes, &call(&1, W, :collector, [{:woke, :_, :_}]))
    assert_taken_once(nodes, :woke, 300)
  end

  # every node writes `jobs` tuples tagged `tag` while 4 takers on every
  # node take them: each is taken once, none is left
  defp assert_taken_once(nodes, tag, jobs) do
    takers =
      for n <- nodes do
        Task.async(fn -> call(n, W, :take_all, [{tag, :_, :_}, 4, 1000], 120_000) end)
      end

    nodes
    |> Enum.map(&Task.async(fn -> call(&1, W, :write, [tag, 1..jobs]) end))
    |> Enum.each(&Task.await/1)

    taken = Enum.flat_map(takers, &Task.await(&1, 120_000))
    written = for n <- nodes, i <- 1..jobs, do: {tag, n.node, i}

    assert length(taken) == length(written), "taken #{length(taken)} of #{length(written)}"
    assert Enum.sort(taken) == Enum.sort(written)
    assert Enum.all?(nodes, &(bb(&1, :rd_all, [{tag, :_, :_}]) == []))
  end

  test "a killed node takes its tuples with it; the rest survive and takes stay exactly-once" do
    [a, b, c] = start(3)
    call(c, W, :report_sink, [:sink])
    call(a, W, :write, [:from_a, 1..50])
    call(b, W, :write, [:job, 1..400])
    eventually(fn -> length(bb(c, :rd_all, [{:_, :_, :_}])) >= 450 end)

    # takers on a and c race for b's jobs; a is killed in the middle
    sink = {:sink, c.node}

    on_a =
      Task.async(fn ->
        catch_exit(call(a, W, :take_all, [{:job, :_, :_}, 4, 500, sink], 60_000))
      end)

    on_c = Task.async(fn -> call(c, W, :take_all, [{:job, :_, :_}, 4, 1500, sink], 60_000) end)
    eventually(fn -> length(call(c, W, :reports, [:sink])) >= 40 end)
    Cluster.kill(a)

    taken_on_c = Task.await(on_c, 60_000)
    Task.await(on_a, 60_000)
    reported = call(c, W, :reports, [:sink])

    # nothing taken twice; at most one job in flight per killed taker is lost
    assert length(Enum.uniq(reported)) == length(reported)
    assert length(reported) in (400 - 4)..400
    assert Enum.all?(taken_on_c, &(&1 in reported))
    assert bb(b, :rd_all, [{:job, :_, :_}]) == []
    # a's tuples are gone from every survivor, b's are untouched
    eventually(fn ->
      bb(b, :rd_all, [{:from_a, :_, :_}]) == [] and bb(c, :rd_all, [{:from_a, :_, :_}]) == []
    end)

    call(b, W, :write, [:after, 1..3])
    eventually(fn -> length(bb(c, :rd_all, [{:after, :_, :_}])) == 3 end)
  end

  test "a partition keeps each side to its own tuples; healing merges without resurrecting takes" do
    [a, b] = start(2)
    on_b = call(b, W, :collector, [{:p, :_, :_}])
    bb(a, :out, [{:p, :a, 1}])
    bb(a, :out, [{:p, :a, 2}])
    eventually(fn -> length(call(b, W, :ask, [on_b])) == 2 end)

    Cluster.partition(a, b)

    # b no longer sees a's tuples, and cannot take them
    eventually(fn -> bb(b, :rd_all, [{:p, :_, :_}]) == [] end)
    assert :none = bb(b, :takep, [{:p, :a, :_}])
    # each side writes and takes on its own
    bb(a, :out, [{:p, :a, 3}])
    bb(b, :out, [{:p, :b, 1}])
    assert {:ok, {:p, :a, 1}} = bb(a, :takep, [{:p, :a, 1}])
    assert Enum.sort(bb(a, :rd_all, [{:p, :_, :_}])) == [{:p, :a, 2}, {:p, :a, 3}]
    assert bb(b, :rd_all, [{:p, :_, :_}]) == [{:p, :b, 1}]

    Cluster.heal(a, b)

    both = [{:p, :a, 2}, {:p, :a, 3}, {:p, :b, 1}]
    eventually(fn -> Enum.sort(bb(a, :rd_all, [{:p, :_, :_}])) == both end)
    eventually(fn -> Enum.sort(bb(b, :rd_all, [{:p, :_, :_}])) == both end)
    # b's subscriber got a's partition-time write once, and nothing twice
    eventually(fn -> length(call(b, W, :ask, [on_b])) == 4 end)
    Process.sleep(200)

    assert call(b, W, :ask, [on_b]) == [{:p, :a, 1}, {:p, :a, 2}, {:p, :b, 1}, {:p, :a, 3}]
    # and exactly-once still holds across the healed pair
    assert {:ok, {:p, :b, 1}} = bb(a, :takep, [{:p, :b, 1}])
    assert :none = bb(b, :takep, [{:p, :b, 1}])
  end

  test "a restarted server resyncs what it missed while down" do
    [a, b] = start(2)
    call(a, W, :write, [:before, 1..10])
    eventually(fn -> length(bb(b, :rd_all, [{:before, :_, :_}])) == 10 end)

    server = call(b, Process, :whereis, [Blackboard.Core.Server])
    call(b, :erlang, :suspend_process, [server])
    # replication messages pile up in the suspended server's mailbox: kill it with them
    call(a, W, :write, [:during, 1..20])
    call(a, Blackboard, :takep, [{:before, :_, 1}])
    Process.sleep(100)
    call(b, Process, :exit, [server, :kill])

    eventually(fn ->
      length(bb(b, :rd_all, [{:during, :_, :_}])) == 20 and
        length(bb(b, :rd_all, [{:before, :_, :_}])) == 9
    end)
  end

  test "writers of one key on two nodes converge on the same tuple" do
    [a, b] = start(2)
    ta = Task.async(fn -> call(a, W, :write, [:pose, 1..300, [key: :shared_pose]]) end)
    tb = Task.async(fn -> call(b, W, :write, [:pose, 1..300, [key: :shared_pose]]) end)
    Task.await(ta)
    Task.await(tb)

    eventually(fn ->
      on_a = bb(a, :rd_all, [{:pose, :_, :_}])
      on_b = bb(b, :rd_all, [{:pose, :_, :_}])
      length(on_a) == 1 and on_a == on_b
    end)
  end

  test "a tuple taken on its owner at once still reaches other nodes' subscribers, and is not left stored there" do
    [a, b] = start(2)
    on_b = call(b, W, :collector, [{:brief, :_, :_}])
    call(a, W, :write_and_take, [:brief, 1..200])

    eventually(fn -> length(call(b, W, :ask, [on_b])) == 200 end)
    assert call(b, W, :ask, [on_b]) == for(n <- 1..200, do: {:brief, a.node, n})
    assert bb(a, :rd_all, [{:brief, :_, :_}]) == []
    # Most were gone before they left a (sent as deliveries only); one the
    # replicator sent before its take was stored on b until the take's
    # delete, which follows by the server's path, reached b.
    eventually(fn -> bb(b, :rd_all, [{:brief, :_, :_}]) == [] end)
  end

  test "a tuple's time to live runs out on every node" do
    [a, b] = start(2)
    bb(a, :out, [{:short, :lived}, [ttl: 300]])
    bb(a, :out, [{:short, :kept}])
    eventually(fn -> length(bb(b, :rd_all, [{:short, :_}])) == 2 end)
    eventually(fn -> bb(b, :rd_all, [{:short, :_}]) == [{:short, :kept}] end)
    assert bb(a, :rd_all, [{:short, :_}]) == [{:short, :kept}]
  end

  test "killing a node's replicator loses nothing: the server restarts and resyncs every peer" do
    [a, b] = start(2)
    on_b = call(b, W, :collector, [{:rep, :_, :_}])
    replicator = call(a, Process, :whereis, [Blackboard.Core.Replicator])
    call(a, :erlang, :suspend_process, [replicator])
    # these writes wait in the suspended replicator's mailbox and die with it
    call(a, W, :write, [:rep, 1..50])
    call(a, Process, :exit, [replicator, :kill])

    eventually(fn -> length(bb(b, :rd_all, [{:rep, :_, :_}])) == 50 end)
    eventually(fn -> length(call(b, W, :ask, [on_b])) == 50 end)
    call(a, W, :write, [:rep, 51..60])
    eventually(fn -> length(call(b, W, :ask, [on_b])) == 60 end)
    assert Enum.sort(call(b, W, :ask, [on_b])) == for(n <- 1..60, do: {:rep, a.node, n})
  end
end
