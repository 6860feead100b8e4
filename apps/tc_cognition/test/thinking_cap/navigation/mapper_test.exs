defmodule ThinkingCap.Navigation.MapperTest do
  # The map builder on a simulated robot, in lockstep with the simulator.
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Grid, Mapper, Maps, OccupancyGrid, Topology}
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir
  @moduletag timeout: 120_000

  @rdf Path.expand("../../../../../priv/examples/office_robot.rdf", __DIR__)
  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  # the office robot patrolling the office, localized on the beacons, its
  # map builder given `mapper_wdf` (the office itself, or nothing)
  defp patrol(dir, mapper_wdf, seconds, world \\ @office) do
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false, step: 0.05, seed: 3)
    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)
    mapper_wdf = mapper_wdf || T.wdf!(dir, [])

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.Localizer, [initial: {1.0, 1.0, 0.0}, initial_sigma: {0.1, 0.05}]},
      mapper: {Mapper, [initial: {1.0, 1.0}, size: {30, 20}], wdf: mapper_wdf},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor, [task: {:patrol, [:lab_bench, :desk_a, :hall_east, :dock]}],
         period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :r,
        rdf: @rdf,
        at: {1.0, 1.0, 0.0},
        controller: {Sim.LockstepController, modules: modules, rdf: @rdf, wdf: @office}
      )

    :ok = Sim.run_for(sim, seconds)
    {:ok, c} = Sim.controller_state(sim, :r)
    {sim, c.lock}
  end

  # the share of the map's labelled cells (free < 20, occupied >= 65)
  # that the true world labels the same, a cell's neighbours allowed at
  # walls (5 cm)
  defp accuracy(%OccupancyGrid{} = map, truth) do
    {ok, all} =
      for r <- 0..(map.height - 1), c <- 0..(map.width - 1), reduce: {0, 0} do
        {ok, all} ->
          v = OccupancyGrid.value(map, {c, r})

          if v < 0 or (v >= 20 and v < 65) do
            {ok, all}
          else
            {tc, tr} = Grid.cell_of(truth, Grid.centre(%Grid{map_grid(map) | cells: ""}, {c, r}))

            blocked =
              for dc <- -1..1, dr <- -1..1, do: not Grid.passable?(truth, {tc + dc, tr + dr})

            good = if v >= 65, do: Enum.any?(blocked), else: not Enum.all?(blocked)
            {if(good, do: ok + 1, else: ok), all + 1}
          end
      end

    ok / all
  end

  defp map_grid(map),
    do: %Grid{
      width: map.width,
      height: map.height,
      cells: "",
      resolution: map.resolution,
      origin: map.origin
    }

  test "builds the office from nothing while patrolling: walls, rooms, doors, segments", %{
    tmp_dir: dir
  } do
    {sim, lock} = patrol(dir, nil, 120)
    assert Sim.status(sim).blocked == 0

    assert {:map, :r, %OccupancyGrid{} = map} = Lockstep.latest(lock, {:map, :r, :_})
    assert map.version > 50
    {:ok, office} = ThinkingCap.Config.read(@office)
    truth = Maps.grid_from_wdf(office, resolution: 0.05)
    assert accuracy(map, truth) > 0.97

    # the patrol saw the lab, office A and the hall: three places, and
    # doors where the lab's and office A's are
    assert {:topology, :r, %Topology{} = topology} = Lockstep.latest(lock, {:topology, :r, :_})
    assert map_size(topology.places) >= 3
    assert Topology.place_of(topology, {3.5, 7.0}) != Topology.place_of(topology, {3.5, 1.5})

    for {x, y} <- [{3.0, 3.0}, {9.5, 3.0}] do
      assert Enum.any?(Map.values(topology.doors), fn %{centre: {dx, dy}} ->
               :math.sqrt((dx - x) ** 2 + (dy - y) ** 2) < 0.3
             end),
             "no door found near {#{x}, #{y}}: #{inspect(Map.values(topology.doors))}"
    end

    assert {:segments, :r, %{segments: segments}} = Lockstep.latest(lock, {:segments, :r, :_})
    # the hall's south wall, y = 0 from x = 0 to 20: covered by segments
    # lying along it, believed occupied, over more than half its length
    # (scans taken while turning fast are left out of the map)
    along =
      for {{x1, y1}, {x2, y2}, degree} <- segments,
          abs(y1) < 0.15 and abs(y2) < 0.15 and degree > 0.5,
          do: abs(x2 - x1)

    assert Enum.sum(along) > 10
  end

  test "a task may name a room of the learned map: \"go to room N\"", %{tmp_dir: dir} do
    # the map built from nothing on a patrol names the lab (north west)
    {sim, lock} = patrol(dir, nil, 120)
    {:topology, :r, topology} = Lockstep.latest(lock, {:topology, :r, :_})
    lab = Topology.place_of(topology, {3.5, 7.0})
    assert "#{lab}" =~ ~r/^room_\d+$/

    # then told to go there by that name, as a dashboard goal would
    task = {:task, :r, %{task: {:go_to, lab}}}
    :ok = Sim.update_controller(sim, :r, &%{&1 | lock: Lockstep.deliver(&1.lock, task)})

    plan =
      Enum.find_value(1..120, fn _ ->
        :ok = Sim.run_for(sim, 1.0)
        {:ok, c} = Sim.controller_state(sim, :r)
        {:plan, :r, plan} = Lockstep.latest(c.lock, {:plan, :r, :_})
        if plan.task == {:go_to, lab} and plan.state in [:done, :failed], do: plan
      end)

    assert %{state: :done, reached: [^lab]} = plan
    {:ok, {x, y, _}} = Sim.pose(sim, :r)
    {:ok, c} = Sim.controller_state(sim, :r)
    {:topology, :r, topology} = Lockstep.latest(c.lock, {:topology, :r, :_})
    assert Topology.place_of(topology, {x, y}) == lab
    assert Sim.status(sim).blocked == 0
  end

  test "a map given a WDF learns the box it was not told about", %{tmp_dir: dir} do
    # the simulator's office has a box in the hall; the robot's does not
    box = [name: :box, polygon: [{5.0, 0.8}, {5.6, 0.8}, {5.6, 1.4}, {5.0, 1.4}]]
    {:ok, office} = ThinkingCap.Config.read(@office)
    world = Path.join(dir, "boxed.wdf")

    File.write!(
      world,
      File.read!(@office)
      |> String.replace("  areas: [", "  obstacles: [#{inspect(box)}],\n  areas: [")
    )

    {_sim, lock} = patrol(dir, @office, 40, world)
    {:map, :r, map} = Lockstep.latest(lock, {:map, :r, :_})
    prior = Maps.grid_from_wdf(office, resolution: 0.05)
    # the map covers the WDF's grid, and the box's west face is in it
    # (within a cell, as the walls below)
    assert {map.width, map.height} == {prior.width, prior.height}

    assert Enum.max(
             for x <- [4.98, 5.03],
                 do: OccupancyGrid.value(map, OccupancyGrid.cell_of(map, {x, 1.1}))
           ) >= 50

    # the walls the WDF drew are still there (within a cell: the estimate
    # the map is built at is good to about that)
    for x <- [6.0, 10.0, 14.0] do
      assert Enum.max(
               for y <- [-0.06, -0.01, 0.01],
                   do: OccupancyGrid.value(map, OccupancyGrid.cell_of(map, {x, y}))
             ) >= 50
    end
  end

  test "saves the map on request, in the map_server format", %{tmp_dir: dir} do
    {_sim, lock} = patrol(dir, nil, 10)
    path = Path.join(dir, "saved.yaml")
    lock = Lockstep.deliver(lock, {:save_map, :r, %{path: path}})

    assert {:map_saved, :r, %{path: ^path, result: :ok}} =
             Lockstep.latest(lock, {:map_saved, :r, :_})

    assert {:ok, saved} = OccupancyGrid.load(path)
    grid = Lockstep.state(lock, :mapper).grid
    current = ThinkingCap.Navigation.Maps.SensedGrid.occupancy(grid)
    assert {saved.width, saved.height} == {current.width, current.height}
    # the map drawn crisp (map_saver's trinary thresholds, walls thinned
    # to their surfaces), cell for cell
    assert saved.data == OccupancyGrid.crisp(current).data
    refute saved.data == current.data

    # a missing directory is made; an unwritable path is reported, not a crash
    nested = Path.join(dir, "new/dir/m.yaml")
    lock = Lockstep.deliver(lock, {:save_map, :r, %{path: nested}})
    assert {:map_saved, :r, %{result: :ok}} = Lockstep.latest(lock, {:map_saved, :r, :_})
    assert File.exists?(nested)

    File.write!(Path.join(dir, "a_file"), "")
    lock = Lockstep.deliver(lock, {:save_map, :r, %{path: Path.join(dir, "a_file/m.yaml")}})

    assert {:map_saved, :r, %{result: {:error, message}}} =
             Lockstep.latest(lock, {:map_saved, :r, :_})

    assert message =~ "a_file"
  end

  test "slam: the loop closure's options reach its pose graph", %{tmp_dir: dir} do
    {_subscriptions, state} =
      Mapper.init([slam: [loop_gap: 12, keep_distance: 0.2]], %{
        name: :mapper,
        robot: :r,
        rdf: @rdf,
        wdf: T.wdf!(dir, [])
      })

    assert state.loops.graph.params.loop_gap == 12
    assert state.loops.params.keep_distance == 0.2
    # the others keep their defaults
    assert state.loops.graph.params.loop_radius == 4.0
  end

  test "a robot with no range sensor cannot build a map", %{tmp_dir: dir} do
    rdf = T.rdf!(dir, sensors: [[name: :odom, type: :odometry]])

    assert_raise ArgumentError, ~r/no laser or sonar/, fn ->
      Mapper.init([], %{name: :mapper, robot: :r, rdf: rdf, wdf: nil})
    end
  end
end
