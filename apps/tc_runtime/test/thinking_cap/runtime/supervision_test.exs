defmodule ThinkingCap.Runtime.SupervisionTest do
  # Hosts modules of two robots in this node's runtime and makes one crash
  # loop: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}
  alias ThinkingCap.Runtime.{Deployment, Supervision}
  alias ThinkingCap.Testing.Cluster
  import ThinkingCap.Testing.Cycle
  import ThinkingCap.Blackboard.Assertions

  @moduletag :tmp_dir

  @cruise "[module: ThinkingCap.Test.Modules.Cruise, activity: :periodic, period: 0.01, deadline: 0.008]"
  @echo "[module: ThinkingCap.Test.Modules.Echo, activity: :event, subscribe: [{:ping, :_, :_}]]"
  @broken "[module: ThinkingCap.Test.Modules.Broken, activity: :periodic, period: 0.01, deadline: 0.008]"

  # A robot's ADF; module names get the robot's name (a periodic activity
  # is known to the timing worker by name).
  defp robot_adf(dir, modules, extra \\ "") do
    robot = :"r#{System.unique_integer([:positive])}"
    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}_#{robot}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")
    File.write!(path, "[\n  robot: :#{robot},\n#{extra}  modules: [\n#{body}\n  ]\n]\n")
    adf = Config.read!(path)
    on_exit(fn -> for m <- adf.modules, do: Runtime.stop({robot, m.name}) end)
    {adf, robot, fn name -> :"#{name}_#{robot}" end}
  end

  # every applied event of `name` already in the mailbox
  defp drain(name, acc \\ []) do
    receive do
      {:tc_cycle, :applied, ^name, event} -> drain(name, [event | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  test "the ADF's layer: given, or by activity" do
    assert Supervision.layer_of(%{activity: :periodic}) == :reactive
    assert Supervision.layer_of(%{activity: :event}) == :cognitive
    assert Supervision.layer_of(%{activity: :background}) == :cognitive
    assert Supervision.layer_of(%{activity: :periodic, layer: :cognitive}) == :cognitive
  end

  test "the ADF checks a module's layer", %{tmp_dir: dir} do
    path = Path.join(dir, "bad.adf")

    File.write!(path, """
    [robot: :r1, modules: [p: [module: ThinkingCap.Test.Modules.Echo, activity: :event,
                               layer: :reflexive],
                           q: [module: ThinkingCap.Test.Modules.Echo, activity: :event,
                               layer: :reactive]]]
    """)

    assert {:error, [error]} = Config.read(path)
    assert error.message =~ "layer"
    assert error.message =~ ":reflexive"

    File.write!(path, """
    [robot: :r1, modules: [p: [module: ThinkingCap.Test.Modules.Echo, activity: :event],
                           q: [module: ThinkingCap.Test.Modules.Echo, activity: :event,
                               layer: :reactive]]]
    """)

    assert {:ok, adf} = Config.read(path)
    assert [%{name: :p, layer: :cognitive}, %{name: :q, layer: :reactive}] = adf.modules
  end

  test "one robot's module crash-loops until its layer gives up: that robot is stopped and " <>
         "says so, the other robot runs on with the same processes",
       %{tmp_dir: dir} do
    {good, rg, g} = robot_adf(dir, drive: @cruise, echo: @echo)
    {bad, rb, b} = robot_adf(dir, drive: @cruise, think: @echo, broken: @broken)

    :ok = Cycle.subscribe(g.(:drive))
    :ok = Cycle.subscribe(b.(:drive))

    {:ok, _} = Runtime.start(good)
    good_pids = for m <- [:drive, :echo], do: Runtime.whereis({rg, g.(m)})
    assert Enum.all?(good_pids, &is_pid/1)
    assert %{kind: :fresh} = applied_until(g.(:drive), &(&1.kind == :fresh))

    {:ok, started} = Runtime.start(bad)
    assert %{layer: :reactive} = Enum.find(started, &(&1.name == b.(:broken)))
    assert %{layer: :cognitive} = Enum.find(started, &(&1.name == b.(:think)))
    think = Runtime.whereis({rb, b.(:think)})

    # the crash loop: 5 restarts in 5 s are forgiven, the 6th crash is not
    assert {:module_gave_up, ^rb, gave_up} = assert_tuple({:module_gave_up, rb, :_}, 10_000)
    module = b.(:broken)
    node = node()

    assert %{module: ^module, layer: :reactive, node: ^node, restarts: 5, seconds: 5} = gave_up
    assert gave_up.reason =~ "RuntimeError: broken sensor"
    # the whole reactive layer of that robot was stopped with it
    assert gave_up.stopped == Enum.sort([b.(:drive), b.(:broken)])

    # that robot is stopped: E-stop latched, its drive's activity gone
    # with the stop as the last command applied for it
    assert {:estop, ^rb, %{engaged: true, by: by}} = assert_tuple({:estop, rb, :_})
    assert by =~ "#{module} gave up"
    assert Runtime.whereis({rb, b.(:drive)}) == nil
    assert Runtime.whereis({rb, module}) == nil
    Cluster.wait_until(fn -> not Map.has_key?(Cycle.timing(), b.(:drive)) end)
    assert %{kind: :fallback, command: :stop} = List.last(drain(b.(:drive)))

    # its cognitive layer was not touched
    assert Runtime.whereis({rb, b.(:think)}) == think

    # the other robot: the same processes, its cycles go on, no stop
    assert good_pids == for(m <- [:drive, :echo], do: Runtime.whereis({rg, g.(m)}))
    drain(g.(:drive))
    %{cycle: c1} = applied_until(g.(:drive), &(&1.kind == :fresh))
    %{cycle: c2} = applied_until(g.(:drive), &(&1.kind == :fresh))
    assert c2 > c1
    Blackboard.out({:ping, rg, 1})
    assert_tuple({:pong, rg, 1})
    refute_tuple({:estop, rg, :_})
    refute_tuple({:module_gave_up, rg, :_})

    # the layer stays down: starting its modules again is refused ...
    assert {:error, [{_, {:layer_gave_up, ^rb, :reactive}}]} =
             Runtime.start(%{bad | modules: Enum.filter(bad.modules, &(&1.name == b.(:drive)))})

    # ... until it is resumed
    assert Runtime.resume(rb) == %{node() => Enum.sort([b.(:drive), b.(:broken)])}
    refute_tuple({:module_gave_up, rb, :_})
    drive = Enum.find(bad.modules, &(&1.name == b.(:drive)))
    assert {:ok, %{layer: :reactive}} = Runtime.start_module(bad, drive)
    assert %{kind: :fresh} = applied_until(b.(:drive), &(&1.kind == :fresh))
  end

  test "a module that crashes now and then is restarted; its layer does not give up",
       %{tmp_dir: dir} do
    {adf, robot, n} = robot_adf(dir, drive: @cruise, echo: @echo)
    {:ok, _} = Runtime.start(adf)

    for _ <- 1..3 do
      pid = Runtime.whereis({robot, n.(:drive)})
      ref = Process.monitor(pid)
      Process.exit(pid, :kill)
      assert_receive {:DOWN, ^ref, :process, ^pid, :killed}
      Cluster.wait_until(fn -> Runtime.whereis({robot, n.(:drive)}) not in [nil, pid] end)
    end

    refute Supervision.gave_up?(robot, :reactive)
    refute_tuple({:module_gave_up, robot, :_})
  end

  test "restarts asked for are not crashes: they never make a layer give up", %{tmp_dir: dir} do
    {adf, robot, n} = robot_adf(dir, drive: @cruise)
    {:ok, _} = Runtime.start(adf)
    :ok = Cycle.subscribe(n.(:drive))

    # more than the reactive layer's 5 restarts in 5 s
    pids =
      for _ <- 1..8 do
        pid = Runtime.whereis({robot, n.(:drive)})
        assert :ok = Runtime.restart({robot, n.(:drive)})
        refute Process.alive?(pid)
        pid
      end

    assert length(Enum.uniq(pids)) == 8
    refute Supervision.gave_up?(robot, :reactive)
    refute_tuple({:module_gave_up, robot, :_})
    assert %{kind: :fresh} = applied_until(n.(:drive), &(&1.kind == :fresh))
  end

  test "a deployment does not start again the modules of a layer that gave up",
       %{tmp_dir: dir} do
    {adf, robot, n} = robot_adf(dir, drive: @cruise, broken: @broken)
    server = :"deployment_#{robot}"
    pid = start_supervised!({Deployment, adf: adf, name: server})

    assert {:module_gave_up, ^robot, %{module: broken}} =
             assert_tuple({:module_gave_up, robot, :_}, 10_000)

    assert broken == n.(:broken)
    assert Supervision.gave_up?(robot, :reactive)

    # a round of placement (a call after it: it has run) leaves them down
    send(pid, :tick)
    assert %{modules: %{} = modules} = Deployment.status(server)
    assert modules[n.(:drive)] == nil
    assert modules[n.(:broken)] == nil

    # resumed, the deployment starts them again on its next round (and
    # the module, still broken, gives up again)
    assert Runtime.resume(robot) == %{node() => Enum.sort([n.(:drive), broken])}
    refute_tuple({:module_gave_up, robot, :_})
    send(pid, :tick)

    assert {:module_gave_up, ^robot, %{module: ^broken}} =
             assert_tuple({:module_gave_up, robot, :_}, 10_000)
  end
end
