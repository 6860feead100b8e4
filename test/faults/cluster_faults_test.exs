defmodule ThinkingCap.FaultSuite.ClusterFaultsTest do
  # Faults across the robot's CPUs: real peer nodes deploying one ADF
  # (ThinkingCap.Runtime.Deployment), a node killed as a power loss would,
  # a network partition and its healing.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Runtime}
  alias ThinkingCap.FaultSuite.Tally
  alias ThinkingCap.Runtime.Deployment
  alias ThinkingCap.Test.NodeWorkers, as: W
  alias ThinkingCap.Testing.Cluster

  @moduletag :faults
  @moduletag :tmp_dir

  @pilot "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.02"
  @echo "[module: ThinkingCap.Test.Modules.Echo, activity: :event, subscribe: [{:ping, :_, :_}]"

  defp write_adf(dir, names, modules, cluster) do
    robot = :"k#{System.unique_integer([:positive])}"

    nodes =
      Enum.map_join(names, ", ", fn {logical, name} ->
        "#{logical}: :\"#{Cluster.node_name(name)}\""
      end)

    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")

    File.write!(
      path,
      "[\n  robot: :#{robot},\n  nodes: [#{nodes}],\n  cluster: [#{cluster}],\n  modules: [\n#{body}\n  ]\n]\n"
    )

    {path, robot}
  end

  defp start(names) do
    nodes = Cluster.start(length(names), apps: [:tc_runtime], names: Keyword.values(names))

    on_exit(fn -> Cluster.stop(nodes) end)
    nodes
  end

  defp host(node, name), do: Cluster.call(node, Deployment, :status, []).modules[name]
  defp bb(node, fun, args), do: Cluster.call(node, Blackboard, fun, args)

  test "a killed node: its modules fail over, the others' tuples survive, takes stay exactly-once",
       %{tmp_dir: dir} do
    names = [a: Cluster.random_name(), b: Cluster.random_name(), c: Cluster.random_name()]

    {path, _robot} =
      write_adf(
        dir,
        names,
        [
          pilot: @pilot <> ", node: :b, standby: [:c]]",
          echo: @echo <> ", node: :b, standby: [:a]]"
        ],
        "connect_every: 0.5, settle: 1"
      )

    [a, b, c] = start(names)
    for n <- [a, b, c], do: {:ok, _} = Cluster.call(n, Runtime, :deploy, [path])
    Cluster.wait_until(fn -> host(a, :pilot) == b.node and host(a, :echo) == b.node end, 15_000)

    # tuples of the survivors, jobs to take, and tuples of the doomed node
    Cluster.call(a, W, :write, [:keep, 1..300])
    Cluster.call(c, W, :write, [:keep, 1..300])
    Cluster.call(c, W, :write, [:job, 1..2_000])
    Cluster.call(b, W, :write, [:doomed, 1..100])
    Cluster.wait_until(fn -> length(bb(a, :rd_all, [{:job, :_, :_}])) == 2_000 end)

    # takers on a and c race for the jobs while b dies
    takers =
      for n <- [a, c],
          do:
            Task.async(fn ->
              Cluster.call(n, W, :take_all, [{:job, :_, :_}, 4, 1_500], 120_000)
            end)

    Cluster.wait_until(fn -> length(bb(c, :rd_all, [{:job, :_, :_}])) < 1_800 end)
    Tally.injected()
    Cluster.kill(b)

    taken = Enum.flat_map(takers, &Task.await(&1, 120_000))

    # modules failed over to their standbys; the pilot's cycle runs on c
    Cluster.wait_until(fn -> host(a, :pilot) == c.node and host(a, :echo) == a.node end, 15_000)

    Cluster.wait_until(fn ->
      (Cluster.call(c, Runtime, :timing, [])[:pilot] || %{cycles: 0}).cycles > 5
    end)

    assert {:ok, {:pong, _, 1}} =
             (fn ->
                bb(c, :out, [{:ping, :x, 1}])
                bb(c, :rd, [{:pong, :x, 1}, 5_000])
              end).()

    # the survivors' tuples are all there, on both survivors; b's are gone
    kept = for n <- [a, c], do: length(bb(n, :rd_all, [{:keep, :_, :_}]))
    lost = Enum.sum(for k <- kept, do: 600 - k)
    Tally.lost(lost)
    assert kept == [600, 600]
    assert bb(a, :rd_all, [{:doomed, :_, :_}]) == []

    # every job taken exactly once
    assert length(taken) == 2_000
    assert length(Enum.uniq(taken)) == 2_000
    assert bb(c, :rd_all, [{:job, :_, :_}]) == []
    Tally.survived()
  end

  test "a partition: each side keeps its own tuples and runs the module it can; healed, one copy",
       %{tmp_dir: dir} do
    names = [a: Cluster.random_name(), b: Cluster.random_name()]

    # no reconnecting by the deployments: the partition lasts until healed
    {path, _robot} =
      write_adf(
        dir,
        names,
        [split: @echo <> ", node: :a, standby: [:b]]"],
        "connect_every: 60, settle: 0.5"
      )

    [a, b] = start(names)
    for n <- [a, b], do: {:ok, _} = Cluster.call(n, Runtime, :deploy, [path])
    Cluster.wait_until(fn -> host(b, :split) == a.node end)

    Cluster.call(a, W, :write, [:p, 1..3])
    Cluster.call(b, W, :write, [:p, 1..3])
    Cluster.wait_until(fn -> length(bb(b, :rd_all, [{:p, :_, :_}])) == 6 end)

    Tally.injected()
    Cluster.partition(a, b)

    # each side: its own tuples only, takes of its own only; b runs a copy
    Cluster.wait_until(fn -> length(bb(b, :rd_all, [{:p, :_, :_}])) == 3 end)
    assert :none = bb(b, :takep, [{:p, a.node, :_}])
    assert {:ok, {:p, _, 1}} = bb(a, :takep, [{:p, a.node, 1}])
    Cluster.call(a, W, :write, [:p, 4..4])
    Cluster.call(b, W, :write, [:p, 4..4])
    Cluster.wait_until(fn -> Cluster.call(b, Runtime, :local_whereis, [:split]) != nil end)

    Cluster.heal(a, b)

    # healed: the tuples of both sides, the take not undone, one copy on a
    expected =
      Enum.sort(for(n <- 2..4, do: {:p, a.node, n}) ++ for(n <- 1..4, do: {:p, b.node, n}))

    Cluster.wait_until(fn ->
      Enum.all?([a, b], &(Enum.sort(bb(&1, :rd_all, [{:p, :_, :_}])) == expected))
    end)

    Cluster.wait_until(fn -> Cluster.call(b, Runtime, :local_whereis, [:split]) == nil end)
    assert Cluster.call(a, Runtime, :local_whereis, [:split]) != nil
    Tally.survived()
  end
end
