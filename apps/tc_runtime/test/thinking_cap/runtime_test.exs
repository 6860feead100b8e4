defmodule ThinkingCap.RuntimeTest do
  # Hosts modules in this node's runtime and kills some: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}
  alias ThinkingCap.Test.Modules
  alias ThinkingCap.Testing.Cluster
  import ThinkingCap.Testing.Cycle

  @moduletag :tmp_dir

  # An ADF with unique module names (modules are found by name cluster-wide).
  defp adf(dir, modules, extra \\ "") do
    robot = :"r#{System.unique_integer([:positive])}"
    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}_#{robot}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")
    File.write!(path, "[\n  robot: :#{robot},\n#{extra}  modules: [\n#{body}\n  ]\n]\n")
    adf = Config.read!(path)
    on_exit(fn -> for m <- adf.modules, do: Runtime.stop(m.name) end)
    {adf, robot, fn name -> :"#{name}_#{robot}" end}
  end

  # two robots' ADFs, each with one module `name` given by `spec`
  defp two_robots(dir, name, spec) do
    robots =
      for _ <- 1..2 do
        robot = :"r#{System.unique_integer([:positive])}"
        path = Path.join(dir, "#{robot}.adf")
        File.write!(path, "[robot: :#{robot}, modules: [#{name}: #{spec}]]")
        {Config.read!(path), robot}
      end

    on_exit(fn -> for {_, r} <- robots, do: Runtime.stop({r, name}) end)
    robots
  end

  test "a module with a lead never starts its cycle before the instant due", %{tmp_dir: dir} do
    me = :"lead_test_#{System.unique_integer([:positive])}"
    Process.register(self(), me)

    {adf, _robot, _name} =
      adf(dir,
        punctual:
          "[module: ThinkingCap.Test.Modules.Punctual, activity: :periodic, period: 0.02, " <>
            "deadline: 0.01, lead: 0.004, params: [report_to: :#{me}]]"
      )

    {:ok, _} = Runtime.start(adf)

    reports =
      for _ <- 1..10 do
        assert_receive {:punctual, started, released}, 2_000
        {started, released}
      end

    # handle_cycle/2 starts at the instant due or after it, never before,
    # though the worker released most of these early
    assert Enum.all?(reports, fn {started, _} -> started >= 0 end)
    assert Enum.any?(reports, fn {_, released} -> released < 0 end)
  end

  test "two robots' modules of the same name are told apart by {robot, name}", %{tmp_dir: dir} do
    name = :"echo_#{System.unique_integer([:positive])}"

    spec =
      "[module: ThinkingCap.Test.Modules.Echo, activity: :event, subscribe: [{:ping, :_, :_}]]"

    [{adf1, r1}, {adf2, r2}] = two_robots(dir, name, spec)
    assert {:ok, [%{robot: ^r1, pid: p1}]} = Runtime.start(adf1)
    assert {:ok, [%{robot: ^r2, pid: p2}]} = Runtime.start(adf2)
    assert p1 != p2

    assert Runtime.whereis({r1, name}) == p1
    assert Runtime.whereis({r2, name}) == p2
    assert Runtime.local_whereis({r2, name}) == p2
    assert Runtime.whereis({:no_such_robot, name}) == nil
    # a bare name finds either
    assert Runtime.whereis(name) in [p1, p2]
    assert Enum.sort(Runtime.whereis_all(name)) == Enum.sort([p1, p2])

    assert [%{robot: ^r1, pid: ^p1}, %{robot: ^r2, pid: ^p2}] =
             Runtime.which_modules()
             |> Enum.filter(&(&1.name == name))
             |> Enum.sort_by(&(&1.robot == r2))

    # restarting one robot's leaves the other's running
    ref = Process.monitor(p1)
    assert :ok = Runtime.restart({r1, name})
    assert_receive {:DOWN, ^ref, :process, ^p1, _}
    Cluster.wait_until(fn -> Runtime.whereis({r1, name}) not in [nil, p1] end)
    assert Runtime.whereis({r2, name}) == p2

    assert :ok = Runtime.stop({r2, name})
    refute Process.alive?(p2)
    assert Runtime.whereis({r2, name}) == nil
    assert is_pid(Runtime.whereis({r1, name}))
  end

  test "a second periodic module of a name already cycling on this node is refused, the first keeps its cycle",
       %{tmp_dir: dir} do
    name = :"cruise_#{System.unique_integer([:positive])}"

    spec =
      "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.01, deadline: 0.005, params: [speed: 0.3]]"

    [{adf1, r1}, {adf2, r2}] = two_robots(dir, name, spec)
    assert {:ok, [%{pid: first}]} = Runtime.start(adf1)

    assert {:error, [{^name, {:periodic_name_taken_on_node, ^name, ^first}}]} =
             Runtime.start(adf2)

    assert Runtime.whereis({r2, name}) == nil
    :ok = Cycle.subscribe(name)
    assert %{kind: :fresh, command: {:vel, 0.3, _}} = applied_until(name, &(&1.kind == :fresh))
    assert Runtime.whereis({r1, name}) == first
  end

  test "an ADF's modules start, report where they run, and each activity kind runs", %{
    tmp_dir: dir
  } do
    {adf, robot, n} =
      adf(dir,
        cruise:
          "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.01, deadline: 0.005, params: [speed: 0.3]]",
        echo:
          "[module: ThinkingCap.Test.Modules.Echo, activity: :event, subscribe: [{:ping, :_, :_}]]",
        idle: "[module: ThinkingCap.Test.Modules.Idle, activity: :background]"
      )

    assert {:ok, started} = Runtime.start(adf)
    assert Enum.map(started, & &1.name) == [n.(:cruise), n.(:echo), n.(:idle)]

    running =
      Runtime.which_modules() |> Enum.filter(&(&1.name in [n.(:cruise), n.(:echo), n.(:idle)]))

    assert [
             %{activity: :periodic, node: node, module: Modules.Cruise},
             %{activity: :event},
             %{activity: :background}
           ] = running

    assert node == node()

    # init's actions ran, with the context
    assert {:ok, {:started, ^robot, %{node: ^node}}} = Blackboard.rd({:started, robot, :_}, 1000)

    # periodic: its commands are applied fresh, cycle after cycle
    :ok = Cycle.subscribe(n.(:cruise))

    assert %{kind: :fresh, command: {:vel, 0.3, c1}} =
             applied_until(n.(:cruise), &(&1.kind == :fresh))

    assert %{kind: :fresh, command: {:vel, 0.3, c2}} = applied(n.(:cruise))
    assert c2 == c1 + 1

    # event: a subscribed tuple is handled
    Blackboard.out({:ping, robot, 7})
    assert {:ok, {:pong, ^robot, 7}} = Blackboard.rd({:pong, robot, 7}, 1000)

    # background: runs, at low priority
    assert {:ok, {:bg, ^robot, %{priority: {:priority, :low}}}} =
             Blackboard.rd({:bg, robot, :_}, 1000)
  end

  test "a slow module misses deadlines: fallbacks are applied and counted, others keep time", %{
    tmp_dir: dir
  } do
    {adf, robot, n} =
      adf(dir,
        slow:
          "[module: ThinkingCap.Test.Modules.Slow, activity: :periodic, period: 0.02, deadline: 0.005, fallback: :halt, params: [sleep_ms: 30]]",
        cruise:
          "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.01, deadline: 0.008]"
      )

    {:ok, _} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:slow))
    :ok = Cycle.subscribe(n.(:cruise))

    assert %{kind: :fallback, command: :halt} = applied_until(n.(:slow), &(&1.kind == :fallback))
    # the module itself hears the fallback that replaced its late result
    assert {:ok, _} = Blackboard.rd({:applied, robot, :halt}, 1000)

    Cluster.wait_until(fn ->
      t = Runtime.timing()
      t[n.(:slow)].fallbacks >= 5 and t[n.(:cruise)].response_us.n >= 20
    end)

    timing = Runtime.timing()
    assert timing[n.(:slow)].late >= 1
    # 30 ms of work for a 5 ms deadline: never in time
    assert timing[n.(:slow)].response_us.n == 0
    # the slow module's misses are its own: the other activity's results
    # are applied fresh, most of them (a loaded machine may make some late;
    # how few is the timing benchmark's business)
    assert timing[n.(:cruise)].response_us.n > timing[n.(:cruise)].fallbacks
    # CPU time: the slow module's own 30 ms of work per cycle
    assert timing[n.(:slow)].cpu_us.min >= 30_000
    # published on the blackboard once a second: a later publication counts the fallbacks
    slow = n.(:slow)

    Cluster.wait_until(
      fn ->
        match?(
          {:ok, {:timing, ^slow, %{fallbacks: f}}} when f >= 1,
          Blackboard.rdp({:timing, slow, :_})
        )
      end,
      3000
    )
  end

  test "restart/1 ends a module cleanly (its terminate runs) and its supervisor starts it again",
       %{tmp_dir: dir} do
    {adf, robot, n} =
      adf(dir, parting: "[module: ThinkingCap.Test.Modules.Parting, activity: :event]")

    {:ok, [%{pid: pid}]} = Runtime.start(adf)
    assert :ok = Runtime.restart(n.(:parting))

    assert {:ok, {:parted, ^robot, %{reason: {:shutdown, :restart_requested}, pid: ^pid}}} =
             Blackboard.rd({:parted, robot, :_}, 1000)

    Cluster.wait_until(fn -> Runtime.whereis(n.(:parting)) not in [nil, pid] end)
    assert {:error, :not_running} = Runtime.restart(:no_such_module)
  end

  test "a crashing module is restarted, and its fallback holds meanwhile", %{tmp_dir: dir} do
    {adf, robot, n} =
      adf(dir,
        crashy:
          "[module: ThinkingCap.Test.Modules.Crashy, activity: :periodic, period: 0.01, subscribe: [{:crash, :_}], fallback: :stop]"
      )

    {:ok, [%{pid: pid}]} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:crashy))
    assert %{kind: :fresh} = applied_until(n.(:crashy), &(&1.kind == :fresh))

    ExUnit.CaptureLog.capture_log(fn ->
      Blackboard.out({:crash, robot})

      assert %{kind: :fallback, command: :stop} =
               applied_until(n.(:crashy), &(&1.kind == :fallback))

      Cluster.wait_until(fn -> Runtime.whereis(n.(:crashy)) not in [nil, pid] end)
    end)

    # the restarted module adds its activity again: subscribe anew, fresh commands resume
    Cluster.wait_until(fn -> Cycle.subscribe(n.(:crashy)) == :ok end)
    assert %{kind: :fresh, command: {:ok, _}} = applied_until(n.(:crashy), &(&1.kind == :fresh))
  end

  test "a module replaced while running misses no cycle", %{tmp_dir: dir} do
    {adf, _robot, n} =
      adf(dir,
        cruise:
          "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.02, deadline: 0.018]"
      )

    {:ok, [%{pid: pid}]} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:cruise))
    applied_until(n.(:cruise), &(&1.kind == :fresh))

    assert {:error, {:module_not_available, No.Such, _}} = Runtime.swap(n.(:cruise), No.Such)
    :ok = Runtime.swap(n.(:cruise), Modules.CruiseV2)

    # the cycles around the swap: the old implementation's last, the new one's first ones
    events = until_swapped(n.(:cruise), 50) ++ for(_ <- 1..3, do: applied(n.(:cruise)))
    assert Enum.all?(events, &(&1.kind == :fresh)), inspect(events)
    assert List.last(events).command |> elem(0) == :vel2
    # the same process, consecutive cycles across the swap
    assert Runtime.whereis(n.(:cruise)) == pid
    cycles = Enum.map(events, & &1.cycle)
    assert cycles == Enum.to_list(hd(cycles)..List.last(cycles))

    assert %{module: Modules.CruiseV2} =
             Enum.find(Runtime.which_modules(), &(&1.name == n.(:cruise)))
  end

  test "a stopped module leaves its fallback applied", %{tmp_dir: dir} do
    {adf, _robot, n} =
      adf(dir,
        cruise:
          "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.01, fallback: :stop]"
      )

    {:ok, _} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:cruise))
    applied_until(n.(:cruise), &(&1.kind == :fresh))
    :ok = Runtime.stop(n.(:cruise))

    assert %{kind: :fallback, command: :stop} =
             applied_until(n.(:cruise), &(&1.kind == :fallback))

    assert Runtime.whereis(n.(:cruise)) == nil
    assert {:error, :not_running} = Runtime.stop(n.(:cruise))
  end

  # The isolation defect seen in tc_robot: a test killed its base module,
  # then stopped it on exit while its supervisor was restarting it; the
  # stop found the dead process, the restarted copy ran on, and its wire
  # kept writing to whatever its device path named afterwards (a later
  # test's pty). The scope of :pg is held so that it still lists the dead
  # process while the supervisor restarts it: the order a loaded machine
  # gives at random.
  test "a module stopped while its supervisor restarts it stays stopped; its wire ends",
       %{tmp_dir: dir} do
    device = Path.join(dir, "line")
    File.write!(device, "")

    {adf, _robot, n} =
      adf(dir,
        wired:
          "[module: ThinkingCap.Test.Modules.Wired, activity: :periodic, period: 0.01, " <>
            "params: [device: #{inspect(device)}]]"
      )

    {:ok, [%{pid: old}]} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:wired))
    applied_until(n.(:wired), &(&1.kind == :fresh and &1.wired))

    scope = Process.whereis(Runtime.scope())
    # the robot's layer supervisor the module runs under
    {:parent, supervisor} = Process.info(old, :parent)
    {:links, before} = Process.info(supervisor, :links)
    :ok = :sys.suspend(scope)

    stop =
      try do
        Process.exit(old, :kill)
        # the supervisor restarts it: the new host waits to join :pg
        Cluster.wait_until(fn ->
          {:links, links} = Process.info(supervisor, :links)
          Enum.any?(links -- before, &is_pid/1)
        end)

        # :pg lists the dead process still; the new one is not in it yet
        assert :pg.get_members(Runtime.scope(), {:module, n.(:wired)}) == [old]
        Task.async(fn -> Runtime.stop(n.(:wired)) end)
      after
        :sys.resume(scope)
      end

    assert :ok = Task.await(stop, 10_000)
    assert Runtime.whereis(n.(:wired)) == nil
    refute Map.has_key?(Cycle.timing(), n.(:wired))

    # the fallback (on the wire) is the last command applied: no copy of
    # the module cycles on, so nothing more is written on its device
    Process.sleep(200)
    assert %{kind: :fallback, wired: true} = last_applied(n.(:wired))
    refute_receive {:tc_cycle, :applied, _, _}, 300
    assert Runtime.whereis(n.(:wired)) == nil
  end

  # the last applied command of `name` in the mailbox
  defp last_applied(name, last \\ nil) do
    receive do
      {:tc_cycle, :applied, ^name, event} -> last_applied(name, event)
    after
      0 -> last
    end
  end

  test "a bad ADF is refused with its errors; nothing starts", %{tmp_dir: dir} do
    path = Path.join(dir, "bad.adf")

    File.write!(
      path,
      "[\n  robot: :r_bad,\n  modules: [m: [module: X.Y, activity: :sometimes]]\n]\n"
    )

    assert {:error, [adf: message]} = Runtime.start(path)

    assert message =~
             "bad.adf:3:40: modules.m.activity: expected one of :periodic, :event, :background, got :sometimes"

    assert {:error, [adf: message]} = Runtime.start(Path.join(dir, "absent.adf"))
    assert message =~ "absent.adf:0:0: cannot read the file"
    assert Runtime.whereis(:m) == nil
  end

  test "a module that cannot start is reported, not crashed on", %{tmp_dir: dir} do
    {adf, _robot, _n} = adf(dir, ghost: "[module: No.Such.Module, activity: :event]")
    assert {:error, [{_name, {:module_not_available, No.Such.Module, node}}]} = Runtime.start(adf)
    assert node == node()
    {adf, _robot, n} = adf(dir, plain: "[module: ThinkingCap.Config, activity: :event]")

    assert {:error, [{_, {:not_a_thinking_cap_module, ThinkingCap.Config, _}}]} =
             Runtime.start(adf)

    assert Runtime.whereis(n.(:plain)) == nil
  end

  test "a module's wire: its :wire bytes go to the worker; a device that cannot be opened is logged and the module runs on",
       %{tmp_dir: dir} do
    missing = Path.join(dir, "no/such/tty")
    module = "module: ThinkingCap.Test.Modules.Wired, activity: :periodic, period: 0.02"

    {adf, _robot, n} =
      adf(dir,
        good: "[#{module}, params: [device: \"/dev/null\"]]",
        bad: "[#{module}, params: [device: #{inspect(missing)}]]"
      )

    :ok = Cycle.subscribe(n.(:good))
    :ok = Cycle.subscribe(n.(:bad))

    log =
      ExUnit.CaptureLog.capture_log(fn ->
        assert {:ok, _} = Runtime.start(adf)

        assert %{command: {:n, _}, wired: true} = applied_until(n.(:good), &(&1.kind == :fresh))

        assert %{command: {:n, _}, wired: false} = applied_until(n.(:bad), &(&1.kind == :fresh))
      end)

    assert log =~ inspect(n.(:bad)) and log =~ missing and log =~ "No such file or directory"
    assert %{wire: "/dev/null"} = Cycle.timing()[n.(:good)]
    assert %{wire: nil} = Cycle.timing()[n.(:bad)]
  end

  test "modules run on the nodes the ADF names", %{tmp_dir: dir} do
    [a, b] = nodes = Cluster.start(2, apps: [:tc_runtime])
    on_exit(fn -> Cluster.stop(nodes) end)

    extra = "  nodes: [main: :\"#{a.node}\", nav: :\"#{b.node}\"],\n"

    {adf, robot, n} =
      adf(
        dir,
        [
          cruise:
            "[module: ThinkingCap.Test.Modules.Cruise, node: :main, activity: :periodic, period: 0.05]",
          echo:
            "[module: ThinkingCap.Test.Modules.Echo, node: :nav, activity: :event, subscribe: [{:ping, :_, :_}]]"
        ],
        extra
      )

    # started from node a, as a release's boot would
    assert {:ok, started} = Cluster.call(a, Runtime, :start, [adf])
    assert Enum.map(started, &{&1.name, &1.node}) == [{n.(:cruise), a.node}, {n.(:echo), b.node}]

    # every node sees where every module runs
    for node <- nodes do
      seen = Cluster.call(node, Runtime, :which_modules, []) |> Enum.map(&{&1.name, &1.node})
      assert {n.(:cruise), a.node} in seen and {n.(:echo), b.node} in seen
    end

    # the module on b reacts to a tuple written on a; the cycle runs on a
    Cluster.call(a, Blackboard, :out, [{:ping, robot, 1}])
    assert {:ok, {:pong, ^robot, 1}} = Cluster.call(a, Blackboard, :rd, [{:pong, robot, 1}, 5000])

    Cluster.wait_until(fn ->
      (Cluster.call(a, Runtime, :timing, [])[n.(:cruise)] || %{cycles: 0}).cycles > 3
    end)
  end

  # applied events up to and including the first one from the new implementation
  defp until_swapped(name, left) when left > 0 do
    event = applied(name)

    case event.command do
      {:vel2, _, _} -> [event]
      _ -> [event | until_swapped(name, left - 1)]
    end
  end
end
