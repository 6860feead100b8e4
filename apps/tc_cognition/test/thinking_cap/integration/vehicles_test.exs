defmodule ThinkingCap.Integration.VehiclesTest do
  # Car-like robots of the warehouse example docking, the whole stack in
  # lockstep with the simulator.
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @moduletag timeout: 180_000

  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @wdf Path.join(@examples, "warehouse.wdf")

  defp dock(vehicle, start, station) do
    rdf = Path.join(@examples, "#{vehicle}.rdf")
    {:ok, sim} = Sim.start_link(world: @wdf, mode: :fast, running: false, step: 0.05, seed: 5)
    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.Localizer, [initial: start, initial_sigma: {0.1, 0.05}]},
      control: {ThinkingCap.Control.VehicleDrive, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor, [task: {:go_to, station}, stuck_after: 40.0], period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, vehicle,
        rdf: rdf,
        at: start,
        controller: {Sim.LockstepController, modules: modules, rdf: rdf, wdf: @wdf}
      )

    plan = run_until_done(sim, vehicle, 180.0)
    :ok = Sim.run_for(sim, 1.0)
    {:ok, pose} = Sim.pose(sim, vehicle)
    {:ok, d} = Description.load(rdf)
    {:ok, world} = Sim.World.load(@wdf)
    {:ok, target} = Sim.World.resolve_pose(world, station)
    {plan, pose, target, d.docking, Sim.status(sim).blocked}
  end

  defp run_until_done(sim, robot, limit) do
    :ok = Sim.run_for(sim, 1.0)
    {:ok, c} = Sim.controller_state(sim, robot)
    {:plan, ^robot, plan} = Lockstep.latest(c.lock, {:plan, robot, :_})

    if plan.state in [:done, :failed] or Sim.time(sim) >= limit,
      do: plan,
      else: run_until_done(sim, robot, limit)
  end

  defp assert_docked(station, {plan, {x, y, th}, {gx, gy, gth}, docking, blocked}) do
    assert plan.state == :done
    assert plan.reached == [station]
    assert :math.sqrt((x - gx) ** 2 + (y - gy) ** 2) <= docking.position_tolerance
    assert abs(normalize_angle(th - gth)) <= docking.heading_tolerance
    assert blocked == 0
  end

  test "the forklift, facing away, turns round and backs into a pallet station forks first" do
    assert_docked(:p_a1_north, dock(:forklift, {15.0, 10.0, 0.0}, :p_a1_north))
  end

  test "the tug drives into a charging station from the far end of the warehouse" do
    assert_docked(:t_south_1, dock(:tug, {25.0, 17.0, 3.0}, :t_south_1))
  end
end
