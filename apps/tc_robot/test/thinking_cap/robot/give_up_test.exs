defmodule ThinkingCap.Robot.GiveUpTest do
  # Two robots' bases and pilots in this node's runtime, one robot's
  # cognitive layer crash-looping: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}
  import ThinkingCap.Blackboard.Assertions
  import ThinkingCap.Testing.Cycle
  import ThinkingCap.Robot.Test.Eventually

  @moduletag :tmp_dir

  defmodule Pilot do
    @moduledoc false
    # drives its robot ahead at every cycle, as a control module would
    use ThinkingCap.Module

    @impl true
    def init(_params, ctx), do: {:ok, ctx.robot}

    @impl true
    def handle_cycle(_release, robot),
      do:
        {[out: {{:drive, robot, %{command: {:velocity, 0.2, 0.0}}}, [key: {:drive, robot}]}],
         robot}
  end

  defmodule Broken do
    @moduledoc false
    # a localizer, say, that crashes at every cycle
    use ThinkingCap.Module

    @impl true
    def handle_cycle(_release, _state), do: raise("no map")
  end

  @rdf """
  [
    name: "test-diff",
    footprint: [radius: 0.2],
    kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.16, max_speed: 0.5],
    sensors: [[name: :bumper, type: :bumper]]
  ]
  """

  # a robot: its base (a test robot whose commands never go stale in the
  # test's time, so only an E-stop stops it), a pilot, and maybe a broken
  # module, all but the base in the cognitive layer
  defp start_robot(dir, broken?) do
    robot = :"g#{System.unique_integer([:positive])}"
    File.write!(Path.join(dir, "r.rdf"), @rdf)
    n = fn name -> :"#{name}_#{robot}" end

    broken =
      if broken?,
        do:
          "#{n.(:broken)}: [module: #{inspect(Broken)}, activity: :periodic, period: 0.01, layer: :cognitive],",
        else: ""

    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: "r.rdf",
      modules: [
        #{n.(:base)}: [module: ThinkingCap.Testing.Robot, activity: :periodic, period: 0.01,
                       deadline: 0.005, fallback: :stop, params: [command_timeout: 60]],
        #{broken}
        #{n.(:pilot)}: [module: #{inspect(Pilot)}, activity: :periodic, period: 0.02,
                        layer: :cognitive]
      ]
    ]
    """)

    adf = Config.read!(path)
    :ok = Cycle.subscribe(n.(:base))
    on_exit(fn -> for m <- adf.modules, do: Runtime.stop({robot, m.name}) end)
    {:ok, _} = Runtime.start(adf)
    {robot, n}
  end

  defp drain(name) do
    receive do
      {:tc_cycle, :applied, ^name, _} -> drain(name)
    after
      0 -> :ok
    end
  end

  test "a robot whose cognitive layer gives up is held stopped by its base; the other drives on",
       %{tmp_dir: dir} do
    {good, g} = start_robot(dir, false)
    ahead = {:velocity, 0.2, 0.0}
    assert %{kind: :fresh} = applied_until(g.(:base), &(&1.command == ahead))
    good_pids = for m <- [:base, :pilot], do: Runtime.whereis({good, g.(m)})

    {bad, b} = start_robot(dir, true)
    base = Runtime.whereis({bad, b.(:base)})

    assert {:module_gave_up, ^bad, gave_up} = assert_tuple({:module_gave_up, bad, :_}, 15_000)
    assert %{module: module, layer: :cognitive, restarts: 10, seconds: 60} = gave_up
    assert module == b.(:broken)
    assert gave_up.reason =~ "no map"
    assert gave_up.stopped == Enum.sort([b.(:broken), b.(:pilot)])

    # its base, in the reactive layer, runs on and applies the stop: the
    # E-stop the runtime latched (its commands would not go stale for 60 s)
    assert Runtime.whereis({bad, b.(:base)}) == base
    assert {:estop, ^bad, %{engaged: true}} = assert_tuple({:estop, bad, :_})

    eventually(fn ->
      assert {:ok, {:control, ^bad, %{mode: :estop, command: :stop}}} =
               Blackboard.rdp({:control, bad, :_})
    end)

    drain(b.(:base))
    assert %{command: :stop} = applied_until(b.(:base), &(&1.kind == :fresh))
    assert %{command: :stop} = applied_until(b.(:base), &(&1.kind == :fresh))

    # the other robot: the same processes, still driving ahead
    assert good_pids == for(m <- [:base, :pilot], do: Runtime.whereis({good, g.(m)}))
    drain(g.(:base))
    assert %{kind: :fresh, command: ^ahead} = applied_until(g.(:base), &(&1.kind == :fresh))
    refute_tuple({:estop, good, :_})
  end
end
