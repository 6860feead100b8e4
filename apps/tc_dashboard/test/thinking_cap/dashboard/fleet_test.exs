defmodule ThinkingCap.Dashboard.FleetTest do
  # The fleet example as bin/run starts it (priv/examples/fleet.adf): read
  # and checked like `mix tc.check`, started by the runtime with the
  # dashboard (on free ports), then its hundred robots and its walkers
  # looked for in the simulator, on the blackboard, in what the
  # dashboard sends browsers and on the page's map in a real browser
  # (Debian's chromium, as the other browser tests); then everything
  # stopped and cleaned away.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Dashboard, Runtime, Sim}
  alias ThinkingCap.Dashboard.Telemetry
  alias ThinkingCap.Dashboard.Test.Browser

  @moduletag :browser
  @moduletag timeout: 120_000
  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @adf Path.join(@examples, "fleet.adf")
  @files ~w(fleet.adf fleet.wdf fleet_robot.rdf)

  test "fleet.adf puts 100 robots and the WDF's walkers in the warehouse, on the dashboard" do
    # the files pass the checks of mix tc.check
    assert Config.check(Enum.map(@files, &Path.join(@examples, &1))) == []
    {:ok, adf} = Config.read(@adf)
    assert adf.robot == :r1
    assert Enum.map(adf.modules, & &1.name) == [:base, :wander, :fleet]

    # as bin/run starts it, the dashboard on free ports
    adf = %{adf | dashboard: Map.merge(adf.dashboard, %{port: 0, rosbridge_port: 0})}
    {:ok, started} = Runtime.start(adf)
    wdf = Path.join(@examples, "fleet.wdf")
    on_exit(fn -> clean_up(started, wdf) end)

    {:ok, sim} = Sim.Worlds.lookup(wdf)
    status = Sim.status(sim)
    assert status.robots == 100
    assert status.walkers == 20
    assert status.mode == :realtime
    robots = Sim.robots(sim)
    fleet = for k <- 1..99, do: :"fleet_#{k}"
    assert Enum.sort(Map.keys(robots)) == Enum.sort([:r1 | fleet])

    # every robot's true pose on the blackboard, and the walkers', where
    # the simulator has them
    for id <- [:r1 | fleet], do: assert({:ok, _} = Blackboard.rd({:sim_pose, id, :_}, 5_000))
    name = Sim.world(sim).name

    assert {:ok, {:sim_walkers, ^name, %{walkers: discs, stamp: stamp}}} =
             Blackboard.rd({:sim_walkers, name, :_}, 5_000)

    assert length(discs) == 20
    assert stamp > 0
    {{x0, y0}, {x1, y1}} = Sim.world(sim).bounds
    for {x, y, r} <- discs, do: assert(x0 < x and x < x1 and y0 < y and y < y1 and r > 0)

    # the fleet moves: the simulated clock runs and the robots wander
    before = robots
    :ok = wait_until(fn -> Sim.time(sim) > 2.0 end, 20_000)
    moved = Enum.count(Sim.robots(sim), fn {id, p} -> distance(p, before[id]) > 0.05 end)
    assert moved >= 50, "#{moved} robots of 100 moved"
    # only their poses are published, not a hundred laser scans
    assert {:ok, _} = Blackboard.rd({:laser, :r1, :_}, 5_000)
    assert Blackboard.rdp({:laser, :fleet_1, :_}) == :none

    # the dashboard has them all to send to a browser
    {:ok, info} = Dashboard.await(10_000)

    :ok =
      wait_until(
        fn ->
          {_version, items} = Telemetry.changes_since(0)
          keys = MapSet.new(items, &elem(&1, 0))

          Enum.all?([:r1 | fleet], &MapSet.member?(keys, "sim_pose/#{&1}")) and
            MapSet.member?(keys, "sim_walkers/#{name}")
        end,
        10_000
      )

    # and the page's map draws them: 100 robots (other tests' robots may
    # be on the blackboard too), 20 walkers
    :ok = Browser.ensure_assets!()
    {:ok, b} = Browser.start_link()
    on_exit(fn -> Browser.stop(b) end)
    Browser.open!(b, info.url <> "&robot=r1")
    ours = :jiffy.encode(Enum.map([:r1 | fleet], &Atom.to_string/1))

    # (a bound on "it did happen", not a measurement: the page first takes
    # the warehouse's 1.7 MB map, on a machine the whole suite loads)
    Browser.wait!(b, "#{ours}.every((id) => tc.drawn[id]) && tc.walkersDrawn === 20",
      timeout: 30_000
    )

    assert Browser.eval!(b, "tc.selected") == "r1"
    Browser.screenshot(b, "fleet")
    assert Browser.page_errors(b) == []
  end

  defp distance({x0, y0, _}, {x1, y1, _}), do: :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)

  defp wait_until(fun, left) when left <= 0, do: if(fun.(), do: :ok, else: :timeout)

  defp wait_until(fun, left) do
    if fun.() do
      :ok
    else
      Process.sleep(50)
      wait_until(fun, left - 50)
    end
  end

  # the modules, the dashboard and the simulation stopped; every tuple of
  # the run's robots and world taken off the blackboard
  defp clean_up(started, wdf) do
    for m <- started, do: Runtime.stop(m.name)
    Dashboard.stop()

    name =
      case Sim.Worlds.lookup(wdf) do
        {:ok, sim} ->
          name = Sim.world(sim).name
          :ok = DynamicSupervisor.terminate_child(ThinkingCap.Sim.Supervisor, sim)
          name

        :error ->
          nil
      end

    ids = [:r1, name | for(k <- 1..99, do: :"fleet_#{k}")] ++ Enum.map(started, & &1.name)

    for id <- ids,
        {tag, ^id, _} <- Blackboard.rd_all({:_, id, :_}),
        do: Blackboard.takep({tag, id, :_})

    :ok
  end
end
