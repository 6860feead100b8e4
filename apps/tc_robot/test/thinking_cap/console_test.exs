defmodule ThinkingCap.ConsoleTest do
  # Hosts a test robot in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  import ExUnit.CaptureIO

  alias ThinkingCap.{Blackboard, Config, Console, Runtime}
  alias ThinkingCap.Testing.Cluster

  @moduletag :tmp_dir

  setup %{tmp_dir: dir} do
    robot = :"c#{System.unique_integer([:positive])}"
    base = :"base_#{robot}"

    File.write!(Path.join(dir, "r.rdf"), """
    [
      name: "console-diff",
      footprint: [radius: 0.2],
      kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.16, max_speed: 0.5]
    ]
    """)

    File.write!(Path.join(dir, "#{robot}.adf"), """
    [
      robot: :#{robot},
      rdf: "r.rdf",
      modules: [
        #{base}: [module: ThinkingCap.Testing.Robot, activity: :periodic, period: 0.01,
                  deadline: 0.005, fallback: :stop]
      ]
    ]
    """)

    {:ok, _} = Runtime.start(Config.read!(Path.join(dir, "#{robot}.adf")))
    on_exit(fn -> Runtime.stop(base) end)
    %{robot: robot, base: base}
  end

  defp driven(robot, command) do
    Cluster.wait_until(fn ->
      match?({:ok, {:driven, _, %{command: ^command}}}, Blackboard.rdp({:driven, robot, :_}))
    end)
  end

  test "estop/1 stops the robot and holds it; release_estop/1 lets autonomy drive again", ctx do
    drive = fn -> Blackboard.out({:drive, ctx.robot, %{command: {:velocity, 0.2, 0.0}}}) end
    drive.()
    driven(ctx.robot, {:velocity, 0.2, 0.0})

    assert capture_io(fn -> Console.estop(ctx.robot) end) =~ "E-stop engaged"
    driven(ctx.robot, :stop)
    drive.()
    Process.sleep(100)
    assert {:ok, {:driven, _, %{command: :stop}}} = Blackboard.rdp({:driven, ctx.robot, :_})

    assert capture_io(fn -> Console.release_estop(ctx.robot) end) =~ "released"
    drive.()
    driven(ctx.robot, {:velocity, 0.2, 0.0})
  end

  test "modules/0 and timing/0 print what runs where and the cycle's figures", ctx do
    output = capture_io(fn -> send(self(), {:modules, Console.modules()}) end)
    assert_received {:modules, modules}
    assert %{node: node, activity: :periodic} = Enum.find(modules, &(&1.name == ctx.base))
    assert node == node()
    assert output =~ ~r/#{ctx.base}\s+ThinkingCap.Testing.Robot\s+#{node()}\s+periodic/

    Cluster.wait_until(fn -> (Runtime.timing()[ctx.base] || %{cycles: 0}).cycles > 5 end)
    output = capture_io(fn -> send(self(), {:timing, Console.timing()}) end)
    assert_received {:timing, %{^node => %{} = activities}}
    assert activities[ctx.base].cycles > 5
    assert output =~ ~r/#{ctx.base}\s+#{node()}\s+\d+\s+[\d.]+ µs/
  end

  test "cluster/0 says when this node runs no deployment" do
    assert capture_io(fn -> send(self(), {:cluster, Console.cluster()}) end) =~ "no deployment"
    assert_received {:cluster, :not_deployed}
  end

  defmodule Cruise do
    @moduledoc false
    # a periodic module that takes live changes of its speed
    use ThinkingCap.Module

    @impl true
    def params do
      [
        max_speed: {{:number_range, 0.0, 1.0}, default: 0.2, doc: "m/s"},
        seed: {:integer, default: 1, read_only: true, doc: "read at start"}
      ]
    end

    @impl true
    def init(_params, ctx), do: {:ok, ctx.params.max_speed}

    @impl true
    def handle_cycle(_release, speed), do: {[command: {:velocity, speed, 0.0}], speed}

    @impl true
    def handle_param(:max_speed, speed, _speed), do: {[], speed}
  end

  defmodule Broken do
    @moduledoc false
    use ThinkingCap.Module

    @impl true
    def handle_cycle(_release, _state), do: raise("broken on purpose")
  end

  test "gave_up/0 lists a module whose layer gave up; resume/1 brings the layer back",
       %{tmp_dir: dir, robot: robot} do
    name = :"broken_#{robot}"
    path = Path.join(dir, "broken.adf")

    File.write!(path, """
    [robot: :#{robot}, modules: [#{name}: [module: #{inspect(Broken)}, activity: :periodic,
      period: 0.01, layer: :cognitive]]]
    """)

    {:ok, _} = Runtime.start(Config.read!(path))
    on_exit(fn -> Runtime.stop({robot, name}) end)
    {:ok, _} = Blackboard.rd({:module_gave_up, robot, :_}, 10_000)

    output = capture_io(fn -> send(self(), {:gave_up, Console.gave_up()}) end)
    assert_received {:gave_up, gave_up}
    assert %{module: ^name, layer: :cognitive} = Enum.find(gave_up, &(&1.robot == robot))
    assert output =~ ~r/#{robot}\s+#{name}\s+cognitive/
    assert output =~ "broken on purpose"

    # the base, in the other layer, runs on, held by the E-stop
    assert {:ok, {:estop, ^robot, %{engaged: true}}} = Blackboard.rdp({:estop, robot, :_})
    assert is_pid(Runtime.whereis({robot, :"base_#{robot}"}))

    assert capture_io(fn -> Console.resume(robot) end) =~ "layers resumed on #{node()}: #{name}"
    assert capture_io(fn -> Console.resume(robot) end) =~ "no layer had given up"
  end

  test "params/1 shows a module's params; param/3 sets one within a cycle, or says why not",
       %{tmp_dir: dir, robot: robot} do
    name = :"cruise_#{robot}"
    path = Path.join(dir, "cruise.adf")

    File.write!(path, """
    [robot: :#{robot}, modules: [#{name}: [module: #{inspect(Cruise)}, activity: :periodic,
      period: 0.01, deadline: 0.005, params: [max_speed: 0.3]]]]
    """)

    {:ok, _} = Runtime.start(Config.read!(path))
    on_exit(fn -> Runtime.stop(name) end)

    output = capture_io(fn -> send(self(), {:params, Console.params(name)}) end)
    assert_received {:params, %{max_speed: 0.3, seed: 1}}
    assert output =~ ~r/max_speed\s+0.3\s+number 0.0..1.0\s+yes\s+m\/s/
    assert output =~ ~r/seed\s+1\s+integer\s+no/

    :ok = ThinkingCap.Cycle.subscribe(name)
    assert capture_io(fn -> Console.param(name, :max_speed, 0.4) end) =~ "#{name}.max_speed = 0.4"
    # the cycle in flight may have been computed before; the next one was not
    flush()
    _ = ThinkingCap.Testing.Cycle.applied_until(name, &(&1.kind == :fresh))

    assert %{command: {:velocity, 0.4, 0.0}} =
             ThinkingCap.Testing.Cycle.applied_until(name, &(&1.kind == :fresh))

    assert {:ok, {:param, ^robot, %{module: ^name, key: :max_speed, value: 0.4, by: :console}}} =
             Blackboard.rdp({:param, robot, :_})

    assert capture_io(fn -> send(self(), {:r, Console.param(name, :max_speed, 4)}) end) =~
             "refused: max_speed: expected a number from 0.0 to 1.0, got 4"

    assert_received {:r, {:error, _}}

    assert capture_io(fn -> Console.param(name, :seed, 2) end) =~ "read-only"
    assert capture_io(fn -> Console.params(:no_such_module) end) =~ "no module"
  end

  defp flush do
    receive do
      _ -> flush()
    after
      0 -> :ok
    end
  end
end
