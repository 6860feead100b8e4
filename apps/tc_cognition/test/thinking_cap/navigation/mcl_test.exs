defmodule ThinkingCap.Navigation.MCLTest do
  # Laser localization on a simulated robot, in lockstep with the simulator.
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{MCL, OccupancyGrid, ParticleFilter}
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir
  @moduletag timeout: 120_000

  @rdf Path.expand("../../../../../priv/examples/office_robot.rdf", __DIR__)
  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  # the office robot patrolling the office, localized by MCL from `initial`
  defp patrol(initial, sigma, seed \\ 3) do
    {:ok, sim} =
      Sim.start_link(world: @office, mode: :fast, running: false, step: 0.05, seed: seed)

    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization: {MCL, [initial: initial, initial_sigma: sigma, seed: seed]},
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

    sim
  end

  # runs `seconds`, returning the estimate's position error and the pose tuple
  defp run(sim, seconds) do
    :ok = Sim.run_for(sim, seconds)
    {:ok, {x, y, _}} = Sim.pose(sim, :r)
    {:ok, c} = Sim.controller_state(sim, :r)
    {:pose, :r, %{pose: {ex, ey, _}} = p} = Lockstep.latest(c.lock, {:pose, :r, :_})
    {:math.sqrt((ex - x) ** 2 + (ey - y) ** 2), p}
  end

  test "tracks the robot without beacons, and finds it again after a kidnapping" do
    sim = patrol({1.0, 1.0, 0.0}, {0.1, 0.05})
    {error, pose} = run(sim, 30)
    assert error < 0.1
    assert pose.status == :tracking and pose.confidence > 0.8
    assert [_, _, _] = pose.covariance

    # carried 14 m away without notice
    {:ok, {x0, _, _}} = Sim.pose(sim, :r)
    :ok = Sim.teleport(sim, :r, {15.0, 1.5, 0.0})
    assert abs(15.0 - x0) > 10

    {error, pose} = run(sim, 15.0)
    assert error < 0.15, "still #{error} m off after the kidnapping"
    assert pose.status == :tracking

    {:ok, c} = Sim.controller_state(sim, :r)

    assert {:particles, :r, %{poses: [{_, _, _} | _] = poses}} =
             Lockstep.latest(c.lock, {:particles, :r, :_})

    assert length(poses) <= 200
  end

  # a hall of 12 x 8 m (0.05 m cells) with two racks whose insides nobody
  # mapped (unknown, as a laser sees through them in the simulator), each
  # with an occupied edge on its west side only, and a pillar in the
  # north-east corner
  defp racks_world(dir) do
    {w, h} = {240, 160}

    cell = fn c, r ->
      x = (c + 0.5) * 0.05
      y = (r + 0.5) * 0.05

      cond do
        c < 2 or r < 2 or c >= w - 2 or r >= h - 2 ->
          0

        x >= 10.8 and x <= 11.2 and y >= 6.6 and y <= 7.0 ->
          0

        (x >= 2.0 and x < 2.1) or (x >= 7.0 and x < 7.1) ->
          if y >= 2 and y <= 6, do: 0, else: 254

        (x >= 2.1 and x <= 5.0) or (x >= 7.1 and x <= 10.0) ->
          if y >= 2 and y <= 6, do: 205, else: 254

        true ->
          254
      end
    end

    map_world(dir, "racks", {w, h}, cell)
  end

  test "a kidnapping between racks the map knows only by one edge is noticed and undone", %{
    tmp_dir: dir
  } do
    wdf = racks_world(dir)
    {:ok, sim} = Sim.start_link(world: wdf, mode: :fast, running: false, step: 0.05, seed: 5)
    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization: {MCL, [initial: {1.0, 1.0, 0.0}, initial_sigma: {0.1, 0.05}, seed: 5]},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor,
         [task: {:patrol, [{6.0, 1.0}, {11.0, 1.0}, {11.0, 4.0}, {6.0, 7.0}, {1.0, 7.0}]}],
         period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :r,
        rdf: @rdf,
        at: {1.0, 1.0, 0.0},
        controller: {Sim.LockstepController, modules: modules, rdf: @rdf, wdf: wdf}
      )

    {error, pose} = run(sim, 20)
    assert error < 0.1
    assert pose.status == :tracking

    # carried into the aisle between the racks, where the east rack's edge
    # and the west rack's far edge stand as a wall and a rack's edge stood
    :ok = Sim.teleport(sim, :r, {6.0, 4.0, :math.pi() / 2})

    {error, pose} = run(sim, 1.0)
    assert error < 0.15 or pose.status != :tracking, "not noticed: #{error} m off, tracking"

    {error, pose} = run(sim, 14.0)
    assert error < 0.15, "still #{error} m off after the kidnapping"
    assert pose.status == :tracking
  end

  # a hall of 12 x 8 m (0.05 m cells) with a pillar near its north-west
  # corner, whose east end (x > 9 m) the map does not know and has no wall
  # (an open end: the laser sees nothing there); with `boxes`, the true
  # world's four boxes of 0.5 m, one of them in the unknown end
  defp open_hall(dir, name, boxes) do
    {w, h} = {240, 160}
    box_at = [{4.5, 2.6}, {6.6, 5.4}, {6.8, 3.4}, {9.6, 4.0}]

    cell = fn c, r ->
      x = (c + 0.5) * 0.05
      y = (r + 0.5) * 0.05

      cond do
        boxes and
            Enum.any?(box_at, fn {bx, by} -> abs(x - bx) <= 0.25 and abs(y - by) <= 0.25 end) ->
          0

        x > 9.0 ->
          205

        c < 2 or r < 2 or r >= h - 2 ->
          0

        x >= 1.0 and x <= 1.4 and y >= 6.6 and y <= 7.0 ->
          0

        true ->
          254
      end
    end

    map_world(dir, name, {w, h}, cell)
  end

  test "boxes the map lacks and its open unknown end do not make the robot lost; a kidnap does",
       %{tmp_dir: dir} do
    truth = open_hall(dir, "truth", true)
    given = open_hall(dir, "given", false)
    {:ok, sim} = Sim.start_link(world: truth, mode: :fast, running: false, step: 0.05, seed: 7)
    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization: {MCL, [initial: {1.5, 1.5, 0.0}, initial_sigma: {0.1, 0.05}, seed: 7]},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor,
         [task: {:patrol, [{8.3, 1.5}, {8.3, 6.5}, {3.0, 6.0}, {1.5, 1.5}]}], period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :r,
        rdf: @rdf,
        at: {1.5, 1.5, 0.0},
        controller: {Sim.LockstepController, modules: modules, rdf: @rdf, wdf: given}
      )

    # round the hall past the boxes and along the open end: never lost
    samples = for _ <- 1..80, do: run(sim, 0.5)
    statuses = samples |> Enum.map(fn {_, p} -> p.status end) |> Enum.uniq()
    worst = samples |> Enum.map(&elem(&1, 0)) |> Enum.max()
    refute :relocalizing in statuses, "took itself for lost: #{inspect(statuses)}"
    assert worst < 0.2, "#{worst} m off"

    # carried 4 m or more away without notice: noticed and found again
    {:ok, {x, y, th}} = Sim.pose(sim, :r)
    to = if x < 5.0, do: {7.5, 4.5, th}, else: {2.5, 4.0, th}
    :ok = Sim.teleport(sim, :r, to)
    assert :math.sqrt((elem(to, 0) - x) ** 2 + (elem(to, 1) - y) ** 2) > 2.0

    {error, pose} = run(sim, 15.0)
    assert error < 0.15, "still #{error} m off after the kidnapping"
    assert pose.status == :tracking
  end

  test "a wrong initial pose, given with its uncertainty, is corrected" do
    # the robot stands at {1, 1, 0}; it is told {1.4, 0.7, 0.25}
    sim = patrol({1.4, 0.7, 0.25}, {0.5, 0.3})
    {error, pose} = run(sim, 10)
    assert error < 0.1
    assert pose.status == :tracking
  end

  test "a map being built is weighed with every beam, sharply; a given map with 40", %{
    tmp_dir: dir
  } do
    empty = T.wdf!(dir, [])
    {_, slam} = MCL.init([], %{name: :localization, robot: :r, rdf: @rdf, wdf: empty})
    assert slam.params[:beams] == 4096 and elem(slam.filter.model, 0) == 0.05

    {_, given} = MCL.init([], %{name: :localization, robot: :r, rdf: @rdf, wdf: @office})
    assert given.params[:beams] == 40 and elem(given.filter.model, 0) == 0.1

    # what the ADF says stands
    opts = [beams: 60, sigma_hit: 0.2]
    {_, own} = MCL.init(opts, %{name: :localization, robot: :r, rdf: @rdf, wdf: empty})
    assert own.params[:beams] == 60 and elem(own.filter.model, 0) == 0.2

    # the model's hits and noise: a given map's as many noise as hits
    # (boxes it lacks), a map being built's mostly hits; the ADF's stand
    assert {_, 0.9, 0.1, _} = slam.filter.model
    assert {_, 0.5, 0.5, _} = given.filter.model

    {_, mine} =
      MCL.init([z_hit: 0.8, z_rand: 0.2], %{
        name: :localization,
        robot: :r,
        rdf: @rdf,
        wdf: @office
      })

    assert {_, 0.8, 0.2, _} = mine.filter.model
  end

  test "with no map it dead-reckons, and takes up a map builder's map when one comes", %{
    tmp_dir: dir
  } do
    empty = T.wdf!(dir, [])
    context = %{name: :localization, robot: :r, rdf: @rdf, wdf: empty}
    {_subscriptions, state} = MCL.init([initial: {1.0, 1.0, 0.0}], context)
    assert state.status == :dead_reckoning

    # odometry moves the estimate
    {_, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.0, 0.0, 0.0}, stamp: 0.0}}, state)
    {actions, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.5, 0.0, 0.0}, stamp: 0.2}}, state)
    assert [{:out, {{:pose, :r, %{pose: {x, _, _}, status: :dead_reckoning}}, _}} | _] = actions
    assert_in_delta x, 1.5, 0.1

    # a map comes: the next scan takes it up
    map = %{
      OccupancyGrid.new(80, 60, resolution: 0.1)
      | data: :binary.copy(<<0>>, 4800),
        version: 3
    }

    {[], state} = MCL.handle_tuple({:map, :r, map}, state)

    scan = %{
      ranges: List.duplicate(3.0, 181),
      angle_min: -1.57,
      angle_increment: 0.0174,
      range_max: 8.0,
      stamp: 0.3
    }

    {_actions, state} = MCL.handle_tuple({:laser, :r, scan}, state)
    # taken after the last odometry (0.2): it waits for the odometry of its time
    assert state.source == nil
    {_actions, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.5, 0.0, 0.0}, stamp: 0.3}}, state)
    assert state.source == :sensed
    assert state.status != :dead_reckoning
  end

  test "a loop closed by the map builder carries the estimate into the map's new frame", %{
    tmp_dir: dir
  } do
    empty = T.wdf!(dir, [])
    context = %{name: :localization, robot: :r, rdf: @rdf, wdf: empty}
    {_subscriptions, state} = MCL.init([initial: {1.0, 1.0, 0.0}], context)
    {_, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.0, 0.0, 0.0}, stamp: 0.0}}, state)
    {actions, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.5, 0.0, 0.0}, stamp: 0.2}}, state)
    assert [{:out, {{:pose, :r, %{pose: before, frame: 0}}, _}} | _] = actions

    map = %{OccupancyGrid.new(80, 60, resolution: 0.1) | data: :binary.copy(<<0>>, 4800)}
    # the map's frame moved: the robot's pose `before` is 0.3 m on and 0.1 rad round
    {bx, by, bth} = before
    after_ = {bx + 0.3, by, bth + 0.1}
    correction = %{from: before, to: after_, frame: 1, map: map, stamp: 0.2}
    {[], state} = MCL.handle_tuple({:map_correction, :r, correction}, state)
    assert state.source == :sensed

    # standing still: the next estimate is where the move put it, in frame 1
    {actions, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.5, 0.0, 0.0}, stamp: 0.3}}, state)
    assert [{:out, {{:pose, :r, %{pose: {x, y, th}, frame: 1}}, _}} | _] = actions
    assert_in_delta x, bx + 0.3, 0.02
    assert_in_delta y, by, 0.02
    assert_in_delta th, bth + 0.1, 0.01

    # a correction of a frame it already has is not applied twice
    {[], state2} = MCL.handle_tuple({:map_correction, :r, correction}, state)
    assert state2.frame == 1
  end

  test "a scan is weighed where the robot was when it was taken, whatever came first" do
    context = %{name: :localization, robot: :r, rdf: @rdf, wdf: @office}
    {_subscriptions, state} = MCL.init([initial: {1.0, 1.0, 0.0}], context)
    {_, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.0, 0.0, 0.0}, stamp: 0.0}}, state)

    scan = fn t ->
      %{
        ranges: List.duplicate(2.0, 181),
        angle_min: -1.57,
        angle_increment: 0.0174,
        range_max: 8.0,
        stamp: t
      }
    end

    # the scan of 0.1 before the odometry of 0.1: held, not weighed
    {[], state} = MCL.handle_tuple({:laser, :r, scan.(0.1)}, state)
    assert state.checked == nil

    {_actions, state} =
      MCL.handle_tuple({:odom, :r, %{pose: {0.02, 0.0, 0.0}, stamp: 0.1}}, state)

    assert state.checked == 0.1

    assert state.held == nil

    # a second scan ahead while one waits: the first is taken at once, the
    # second waits, and the odometry of its time releases it
    {_, state} = MCL.handle_tuple({:laser, :r, scan.(0.2)}, state)
    assert {:laser, %{stamp: 0.2}} = state.held
    {_, state} = MCL.handle_tuple({:laser, :r, scan.(0.3)}, state)
    assert {:laser, %{stamp: 0.3}} = state.held
    {_, state} = MCL.handle_tuple({:odom, :r, %{pose: {0.2, 0.0, 0.0}, stamp: 0.4}}, state)
    assert state.held == nil
    assert state.checked == 0.3
  end

  test "garbage tuples are ignored" do
    context = %{name: :localization, robot: :r, rdf: @rdf, wdf: @office}
    {_subscriptions, state} = MCL.init([initial: :dock], context)

    for tuple <- [
          {:map, :r, "not a map"},
          {:laser, :r, %{ranges: "no list"}},
          {:odom, :r, %{pose: :nowhere, stamp: 1.0}},
          {:laser, :other_robot, %{ranges: []}}
        ] do
      assert {[], ^state} = MCL.handle_tuple(tuple, state)
    end
  end

  test "a robot with no laser, or an unknown initial waypoint, is refused with the reason", %{
    tmp_dir: dir
  } do
    no_laser = T.rdf!(dir, sensors: [[name: :odom, type: :odometry]])

    assert_raise ArgumentError, ~r/no laser/, fn ->
      MCL.init([], %{name: :localization, robot: :r, rdf: no_laser, wdf: @office})
    end

    assert_raise ArgumentError, ~r/:nowhere is not a waypoint/, fn ->
      MCL.init([initial: :nowhere], %{name: :localization, robot: :r, rdf: @rdf, wdf: @office})
    end
  end

  test "publish_period is a live parameter; the filter's make-up is read-only" do
    lock =
      Lockstep.new(
        robot: :r,
        rdf: @rdf,
        wdf: @office,
        modules: [localization: {MCL, [initial: {1.0, 1.0, 0.0}]}]
      )

    # odometry alone for a second, every 50 ms: the estimates it publishes
    odometry = fn lock, from ->
      lock = Lockstep.clear_outs(lock)

      lock =
        Enum.reduce(0..19, lock, fn i, lock ->
          t = from + i * 0.05
          Lockstep.deliver(lock, {:odom, :r, %{pose: {t * 0.1, 0.0, 0.0}, stamp: t}})
        end)

      {lock, Enum.count(Lockstep.outs(lock), &match?({:pose, :r, _}, &1))}
    end

    {lock, every_tenth} = odometry.(lock, 0.0)
    assert every_tenth >= 9

    assert {:ok, lock} = Lockstep.set_param(lock, :localization, :publish_period, 0.5)
    {lock, every_half} = odometry.(lock, 1.0)
    assert every_half in 2..3

    assert {:error, message} = Lockstep.set_param(lock, :localization, :particles, 100)
    assert message =~ "particles of ThinkingCap.Navigation.MCL is read-only"
  end

  # two rooms of 8 x 4 m side by side, walls 0.1 m thick (`rects`), as a
  # map_server map
  defp two_rooms(dir, rects) do
    inside? = fn x, y ->
      Enum.any?(rects, fn {x0, y0, x1, y1} -> x >= x0 and x <= x1 and y >= y0 and y <= y1 end)
    end

    cell = fn c, r -> if inside?.((c + 0.5) * 0.05, (r + 0.5) * 0.05), do: 0, else: 254 end
    map_world(dir, "rooms", {320, 80}, cell)
  end

  # a world of one map_server map (0.05 m cells; `cell.(col, row)` the
  # pixel, row 0 at the bottom), written into `dir`; returns its WDF
  defp map_world(dir, name, {w, h}, cell) do
    # the image's first row is the map's top
    pixels = for r <- (h - 1)..0, c <- 0..(w - 1), into: <<>>, do: <<cell.(c, r)>>
    File.write!(Path.join(dir, "#{name}.pgm"), ["P5\n#{w} #{h}\n255\n", pixels])

    File.write!(
      Path.join(dir, "#{name}.yaml"),
      "image: #{name}.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\n" <>
        "occupied_thresh: 0.65\nfree_thresh: 0.196\nnegate: 0\n"
    )

    path = Path.join(dir, "#{name}.wdf")
    File.write!(path, ~s([name: "#{name}", map: [yaml: "#{name}.yaml"]]))
    path
  end

  # the office robot's laser (181 beams over a half turn, 8 m, 5 cm ahead
  # of the centre) from `pose`, among axis-aligned rectangles
  defp scan_among(rects, {x, y, th}, stamp) do
    {sx, sy} = {x + 0.05 * :math.cos(th), y + 0.05 * :math.sin(th)}

    ranges =
      for i <- 0..180 do
        a = th - :math.pi() / 2 + i * :math.pi() / 180
        {dx, dy} = {:math.cos(a), :math.sin(a)}
        rects |> Enum.map(&entry({sx, sy}, {dx, dy}, &1)) |> Enum.min() |> min(8.0)
      end

    %{
      ranges: ranges,
      angle_min: -:math.pi() / 2,
      angle_increment: :math.pi() / 180,
      range_min: 0.12,
      range_max: 8.0,
      stamp: stamp
    }
  end

  # where a ray from inside the room enters a rectangle (slab method)
  defp entry({ox, oy}, {dx, dy}, {x0, y0, x1, y1}) do
    {tx0, tx1} = slab(ox, dx, x0, x1)
    {ty0, ty1} = slab(oy, dy, y0, y1)
    t_in = max(tx0, ty0)
    if t_in <= min(tx1, ty1) and t_in > 0, do: t_in, else: 1.0e9
  end

  defp slab(o, d, lo, hi) when abs(d) < 1.0e-12,
    do: if(o >= lo and o <= hi, do: {-1.0e9, 1.0e9}, else: {1.0e9, -1.0e9})

  defp slab(o, d, lo, hi) do
    {a, b} = {(lo - o) / d, (hi - o) / d}
    {min(a, b), max(a, b)}
  end

  test "a box that makes a place away fit one scan better does not move the robot", %{
    tmp_dir: dir
  } do
    # room A (x < 8) has a pillar in its north-west corner; room B (x > 8)
    # a wall of 2 m across it, 0.6 m ahead of where the robot will stand
    # in room A, in front of a box of the same size the map lacks: there,
    # facing east, the robot sees what it would see in room B
    rects = [
      {0.0, 0.0, 16.0, 0.1},
      {0.0, 3.9, 16.0, 4.0},
      {0.0, 0.0, 0.1, 4.0},
      {15.9, 0.0, 16.0, 4.0},
      {7.95, 0.0, 8.05, 4.0},
      {0.8, 3.0, 1.2, 3.4},
      {10.6, 1.0, 11.0, 3.0}
    ]

    wdf = two_rooms(dir, rects)
    truth = [{2.6, 1.0, 3.0, 3.0} | rects]
    context = %{name: :localization, robot: :r, rdf: @rdf, wdf: wdf}
    {_, state} = MCL.init([initial: {0.9, 2.0, 0.0}, initial_sigma: {0.05, 0.02}], context)

    # up to the box, a quarter turn left (the pillar comes into view) and
    # north along the box: 0.02 m or 0.08 rad a step of 0.1 s, the
    # odometry exact
    legs = [{52, {0.02, 0.0}}, {20, {0.0, :math.pi() / 40}}, {60, {0.02, 0.0}}]

    moves = Enum.flat_map(legs, fn {n, move} -> List.duplicate(move, n) end)

    {_, _state, worst, statuses} =
      Enum.reduce(Enum.with_index(moves, 1), {{0.9, 2.0, 0.0}, state, 0.0, []}, fn
        {{d, turn}, i}, {{x, y, th}, state, worst, statuses} ->
          pose = {x + d * :math.cos(th), y + d * :math.sin(th), th + turn}
          t = i * 0.1
          {_, state} = MCL.handle_tuple({:odom, :r, %{pose: pose, stamp: t}}, state)
          {_, state} = MCL.handle_tuple({:laser, :r, scan_among(truth, pose, t)}, state)
          {{ex, ey, _}, _} = ParticleFilter.estimate(state.filter)
          error = :math.sqrt((ex - elem(pose, 0)) ** 2 + (ey - elem(pose, 1)) ** 2)
          {pose, state, max(worst, error), [state.status | statuses]}
      end)

    refute :relocalizing in statuses, "took itself for lost: #{inspect(Enum.uniq(statuses))}"
    assert worst < 0.2, "#{worst} m off"
  end
end
