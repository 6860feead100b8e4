defmodule ThinkingCap.Runtime.DeploymentTest do
  # Real peer nodes, each deploying the same ADF, as a release's boot does.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Runtime}
  alias ThinkingCap.Runtime.Deployment
  alias ThinkingCap.Testing.Cluster

  @moduletag :tmp_dir
  @moduletag timeout: 120_000

  # An ADF over two logical nodes, :main and :nav, on nodes of the given
  # short names; `cluster` overrides the timing of connecting and settling.
  defp write_adf(dir, names, modules, cluster \\ "connect_every: 0.2, settle: 0.5") do
    robot = :"r#{System.unique_integer([:positive])}"
    [main, nav] = Enum.map(names, &Cluster.node_name/1)
    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      nodes: [main: :"#{main}", nav: :"#{nav}"],
      cluster: [#{cluster}],
      modules: [
    #{body}
      ]
    ]
    """)

    {path, robot}
  end

  defp start_nodes(names, opts \\ []) do
    nodes =
      Cluster.start(length(names), [apps: [:tc_runtime], names: names, connect: false] ++ opts)

    on_exit(fn -> Cluster.stop(nodes) end)
    nodes
  end

  defp deploy(node, path), do: {:ok, _} = Cluster.call(node, Runtime, :deploy, [path])
  defp status(node), do: Cluster.call(node, Deployment, :status, [])
  defp host(node, name), do: status(node).modules[name]

  defp await_host(node, name, expected) do
    Cluster.wait_until(fn -> host(node, name) == expected end, 15_000)
  end

  @cruise "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.05"
  @echo "[module: ThinkingCap.Test.Modules.Echo, activity: :event, subscribe: [{:ping, :_, :_}]"

  test "each node runs its own modules, connects to the missing one when it comes, reports it meanwhile",
       %{tmp_dir: dir} do
    names = [Cluster.random_name(), Cluster.random_name()]

    {path, robot} =
      write_adf(dir, names,
        cruise: @cruise <> ", node: :main]",
        echo: @echo <> ", node: :nav]",
        spare: @echo <> ", node: :nav, standby: [:main]]"
      )

    [a] = start_nodes(Enum.take(names, 1))
    deploy(a, path)

    # alone: nav is missing; its module with a standby runs here, the other waits
    await_host(a, :cruise, a.node)
    await_host(a, :spare, a.node)
    assert %{logical: :main, up: [:main], missing: [:nav], unplaced: [:echo]} = status(a)

    assert [{:cluster, ^robot, %{node: node, missing: [:nav], unplaced: [:echo]}}] =
             Cluster.call(a, Blackboard, :rd_all, [{:cluster, robot, :_}])

    assert node == a.node

    # nav comes up (same cookie), deploys the same ADF: the nodes find each
    # other, echo starts there; spare stays where it failed over (manual)
    [b] = start_nodes(Enum.drop(names, 1), cookie: Cluster.cookie(a))
    deploy(b, path)
    await_host(a, :echo, b.node)
    assert %{up: [:main, :nav], missing: [], unplaced: []} = status(a)
    assert %{logical: :nav, missing: []} = status(b)
    assert host(b, :spare) == a.node
    assert host(b, :cruise) == a.node

    # moved back by command
    assert :ok = Cluster.call(a, Deployment, :move, [:spare, :nav])
    await_host(a, :spare, b.node)
    assert Cluster.call(a, Runtime, :local_whereis, [:spare]) == nil

    # each module runs once
    for name <- [:cruise, :echo, :spare] do
      assert length(Cluster.call(a, Runtime, :whereis_all, [name])) == 1
    end
  end

  test "a killed node's modules fail over to their standbys and, with failback: :auto, come back",
       %{tmp_dir: dir} do
    names = [Cluster.random_name(), Cluster.random_name()]

    {path, robot} =
      write_adf(dir, names,
        auto: @cruise <> ", node: :nav, standby: [:main], failback: :auto]",
        manual: @echo <> ", node: :nav, standby: [:main]]",
        lonely: @echo <> ", node: :nav]"
      )

    [a, b] = start_nodes(names)
    cookie = Cluster.cookie(a)
    deploy(a, path)
    deploy(b, path)
    for name <- [:auto, :manual, :lonely], do: await_host(a, name, b.node)

    # a tuple written on a survives b's death
    :ok = Cluster.call(a, Blackboard, :out, [{:note, robot, %{from: :a}}])
    Cluster.kill(b)

    await_host(a, :auto, a.node)
    await_host(a, :manual, a.node)
    assert %{missing: [:nav], unplaced: [:lonely]} = status(a)
    assert {:ok, _} = Cluster.call(a, Blackboard, :rdp, [{:note, robot, :_}])

    # the failed-over periodic module runs its cycle on a
    Cluster.wait_until(fn ->
      (Cluster.call(a, Runtime, :timing, [])[:auto] || %{cycles: 0}).cycles > 3
    end)

    # b is back under its name: auto goes home, manual stays, lonely returns
    [b] = start_nodes(Enum.drop(names, 1), cookie: cookie)
    deploy(b, path)
    await_host(a, :auto, b.node)
    await_host(a, :lonely, b.node)
    assert host(a, :manual) == a.node
    assert Cluster.call(a, Runtime, :local_whereis, [:auto]) == nil
  end

  test "a module that hands off resumes on its standby from its last handoff",
       %{tmp_dir: dir} do
    names = [Cluster.random_name(), Cluster.random_name()]

    {path, robot} =
      write_adf(dir, names,
        counter:
          "[module: ThinkingCap.Test.Modules.Counter, activity: :periodic, period: 0.02, " <>
            "node: :nav, standby: [:main], handoff_every: 0.1]"
      )

    [a, b] = start_nodes(names)
    deploy(a, path)
    deploy(b, path)
    await_host(a, :counter, b.node)

    count = fn node ->
      case Cluster.call(node, Blackboard, :rdp, [{:count, robot, :_}]) do
        {:ok, {:count, _, count}} -> count
        :none -> nil
      end
    end

    Cluster.wait_until(fn -> match?(%{n: n} when n >= 40, count.(a)) end, 15_000)
    counted = count.(a).n
    Cluster.kill(b)

    await_host(a, :counter, a.node)
    Cluster.wait_until(fn -> match?(%{node: node} when node == a.node, count.(a)) end, 15_000)

    # on from the count handed off at most 0.1 s (5 cycles) before the kill
    assert %{resumed_from: from} = count.(a)
    assert is_integer(from) and from >= counted - 5
  end

  test "a partition runs a copy on each side; once healed the preferred copy stays",
       %{tmp_dir: dir} do
    names = [Cluster.random_name(), Cluster.random_name()]
    # no reconnecting by the deployments: the partition lasts until healed
    {path, _robot} =
      write_adf(
        dir,
        names,
        [split: @echo <> ", node: :main, standby: [:nav]]"],
        "connect_every: 60, settle: 0.5"
      )

    [a, b] = start_nodes(names)
    deploy(a, path)
    deploy(b, path)
    Cluster.connect(a, b)
    await_host(b, :split, a.node)

    Cluster.partition(a, b)
    Cluster.wait_until(fn -> Cluster.call(b, Runtime, :local_whereis, [:split]) != nil end)
    assert Cluster.call(a, Runtime, :local_whereis, [:split]) != nil

    Cluster.heal(a, b)

    Cluster.wait_until(fn -> Cluster.call(b, Runtime, :local_whereis, [:split]) == nil end)
    assert Cluster.call(a, Runtime, :local_whereis, [:split]) != nil
    assert host(b, :split) == a.node
  end

  test "a node not in the ADF, or a module without a node, is refused with the file named",
       %{tmp_dir: dir} do
    names = [Cluster.random_name(), Cluster.random_name()]
    {path, _} = write_adf(dir, names, x: @echo <> ", node: :main]")

    assert {:error, message} = Runtime.deploy(path)
    assert message =~ path
    assert message =~ "is not one of the ADF's nodes"

    [a] = start_nodes(Enum.take(names, 1))
    {path, _} = write_adf(dir, names, y: @echo <> "]")
    assert {:error, message} = Cluster.call(a, Runtime, :deploy, [path])
    assert message =~ "must name their node"

    assert {:error, message} = Runtime.deploy(Path.join(dir, "missing.adf"))
    assert message =~ "missing.adf"
  end

  test "two robots of one cluster each run their own module of a shared name", %{tmp_dir: dir} do
    [name_a, name_b] = [Cluster.random_name(), Cluster.random_name()]

    adf = fn node_name ->
      robot = :"r#{System.unique_integer([:positive])}"
      path = Path.join(dir, "#{robot}.adf")

      File.write!(path, """
      [robot: :#{robot}, nodes: [main: :"#{Cluster.node_name(node_name)}"],
       cluster: [connect_every: 0.2, settle: 0.5],
       modules: [shared: #{@echo}, node: :main]]]
      """)

      {path, robot}
    end

    {path_a, robot_a} = adf.(name_a)
    {path_b, robot_b} = adf.(name_b)
    [a, b] = start_nodes([name_a, name_b])
    Cluster.connect(a, b)
    deploy(a, path_a)
    deploy(b, path_b)

    await_host(a, :shared, a.node)
    await_host(b, :shared, b.node)
    pid_a = Cluster.call(a, Runtime, :whereis, [{robot_a, :shared}])
    pid_b = Cluster.call(a, Runtime, :whereis, [{robot_b, :shared}])
    assert node(pid_a) == a.node and node(pid_b) == b.node

    # and they stay so: neither deployment takes the other's for its own
    Process.sleep(1_000)
    assert Cluster.call(b, Runtime, :whereis, [{robot_a, :shared}]) == pid_a
    assert Cluster.call(b, Runtime, :whereis, [{robot_b, :shared}]) == pid_b
    assert length(Cluster.call(a, Runtime, :whereis_all, [:shared])) == 2
  end
end
