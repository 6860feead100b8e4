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
end
