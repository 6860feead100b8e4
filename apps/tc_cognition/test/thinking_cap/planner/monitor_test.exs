defmodule ThinkingCap.Planner.MonitorTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Planner.Monitor

  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  # A hall along the south and one room north of it with two doors.
  @two_doors """
  [
    name: "two doors",
    walls: [
      {{0, 0}, {12, 0}}, {{12, 0}, {12, 8}}, {{12, 8}, {0, 8}}, {{0, 8}, {0, 0}},
      {{0, 3}, {2.5, 3}}, {{3.5, 3}, {8.5, 3}}, {{9.5, 3}, {12, 3}}
    ],
    rooms: [[name: :room, polygon: [{0, 3}, {12, 3}, {12, 8}, {0, 8}]]],
    corridors: [[name: :hall, polygon: [{0, 0}, {12, 0}, {12, 3}, {0, 3}]]],
    doors: [
      [name: :west, from: {2.5, 3}, to: {3.5, 3}, connects: [:hall, :room]],
      [name: :east, from: {8.5, 3}, to: {9.5, 3}, connects: [:hall, :room]]
    ],
    waypoints: [[name: :desk, at: {3.0, 6.0}], [name: :start, at: {3.0, 1.0}]]
  ]
  """

  defp start(wdf, task, handoff \\ nil) do
    context = %{
      name: :planner,
      robot: :r,
      node: node(),
      activity: :periodic,
      rdf: nil,
      wdf: wdf,
      handoff: handoff
    }

    {actions, state} = Monitor.init([task: task], context)
    assert {:subscribe, {:pose, :r, :_}} in actions
    state
  end

  defp cycle(state, t) do
    {actions, state} = Monitor.handle_cycle(%{cycle: 0, scheduled_ns: round(t * 1.0e9)}, state)
    [{{:plan, :r, plan}, _opts}] = for {:out, {{:plan, _, _}, _} = o} <- actions, do: o
    {plan, actions, state}
  end

  # obstacle evidence across a door `d` m straight ahead of the robot
  defp shut_ahead(d) do
    points = for y <- [-0.3, -0.15, 0.0, 0.15, 0.3], do: {d, y}
    %{LPS.from_points(points) | evidence: for({x, y} <- points, do: {x, y, 0.9, 0.0})}
  end

  defp pose(state, pose), do: elem(Monitor.handle_tuple({:pose, :r, %{pose: pose}}, state), 1)
  defp lps(state, lps), do: elem(Monitor.handle_tuple({:lps, :r, lps}, state), 1)

  # a monitor with no WDF, given the map builder's map (`w` x `h` cells of
  # 5 cm, `cell.(c, r)` each) and standing at `at`: one cycle's plan,
  # actions and state
  defp on_sensed_map(dir, task, {w, h}, cell, at) do
    empty = Path.join(dir, "empty.wdf")
    File.write!(empty, "[name: \"nothing known\"]")
    data = for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>>, do: <<cell.(c, r)::signed-8>>
    grid = ThinkingCap.Navigation.OccupancyGrid.new(w, h, resolution: 0.05)

    {_, state} =
      Monitor.handle_tuple({:map, :r, %{grid | data: data, version: 1}}, start(empty, task))

    cycle(pose(state, at), 1.0)
  end

  @tag :tmp_dir
  test "exploring: a first map of the ground under the robot and a few echoes is waited on", %{
    tmp_dir: dir
  } do
    # 4 x 4 m: unknown but for a few free cells under the robot at {2, 2}
    # (too few to make a frontier) and two sonar echoes
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        abs(x - 2) < 0.05 and abs(y - 2) < 0.05 -> 0
        {c, r} in [{5, 70}, {75, 10}] -> 100
        true -> -1
      end
    end

    {plan, actions, _state} = on_sensed_map(dir, :explore, {80, 80}, cell, {2.0, 2.0, 0.0})
    assert plan.state == :waiting
    refute Enum.any?(actions, &match?({:out, {:save_map, _, _}}, &1))
  end

  @tag :tmp_dir
  test "exploring: frontiers given up are tried once more before it is done", %{tmp_dir: dir} do
    # 4 x 4 m known, a wall across x = 2; beyond it a strip of free floor
    # and, past x = 3.5, unknown space: a frontier no path reaches
    cell = fn c, _r ->
      x = (c + 0.5) * 0.05

      cond do
        x > 2.0 and x < 2.1 -> 100
        x > 3.5 -> -1
        true -> 0
      end
    end

    {plan, _actions, state} = on_sensed_map(dir, :explore, {80, 80}, cell, {1.0, 2.0, 0.0})
    assert plan.state == :done
    # given up, tried in a second round, given up again
    assert state.rounds == 2
    assert [_] = state.given_up
  end

  @tag :tmp_dir
  test "exploring: a frontier is dropped once seen, though unknown space lies behind a wall by it",
       %{tmp_dir: dir} do
    # 4 x 4 m walled round, known free west of x = 2.5, unknown east of it:
    # one frontier along x = 2.5
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        x < 0.1 or y < 0.1 or x > 3.9 or y > 3.9 -> 100
        x < 2.5 -> 0
        true -> -1
      end
    end

    {plan, _actions, state} = on_sensed_map(dir, :explore, {80, 80}, cell, {1.0, 2.0, 0.0})
    assert plan.state == :moving
    {fx, _} = state.target
    assert abs(fx - 2.5) < 0.1

    # the next map: free up to a wall along x = 2.6 to 2.7, unknown behind
    # it, 0.2 m from the frontier's point: no frontier is left
    seen = fn c, r ->
      x = (c + 0.5) * 0.05

      cond do
        cell.(c, r) != -1 -> cell.(c, r)
        x < 2.6 -> 0
        x < 2.7 -> 100
        true -> -1
      end
    end

    data = for r <- 0..79, c <- 0..79, into: <<>>, do: <<seen.(c, r)::signed-8>>
    map = %{state.map | data: data, version: state.map.version + 1}
    {_, state} = Monitor.handle_tuple({:map, :r, map}, state)
    {plan, _actions, _state} = cycle(state, 2.0)
    assert plan.state == :done
  end

  # 8 x 4 m walled round, known free but for what lies beyond a wall
  # along x = 6 with a 0.8 m door at y = 2 (unknown), and with `north`,
  # unknown space north of y = 2.6 west of x = 4
  defp door_east(north) do
    fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        x < 0.1 or y < 0.1 or x > 7.9 or y > 3.9 -> 100
        x >= 6.0 and x < 6.1 and abs(y - 2.0) > 0.4 -> 100
        x >= 6.0 -> -1
        north and x < 4.0 and y > 2.6 -> -1
        true -> 0
      end
    end
  end

  defp next_map(state, cell) do
    %{width: w, height: h} = state.map
    data = for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>>, do: <<cell.(c, r)::signed-8>>
    map = %{state.map | data: data, version: state.map.version + 1}
    elem(Monitor.handle_tuple({:map, :r, map}, state), 1)
  end

  @tag :tmp_dir
  test "exploring: with a hysteresis, a frontier much cheaper than the target is taken on the way",
       %{
         tmp_dir: dir
       } do
    # a map showing unknown space 0.6 m north of the robot, opening onto
    # more than the door: with a hysteresis, taken, but only when weighed
    # again (5 s on), and not by less than the hysteresis; without (the
    # default), not taken
    for {hysteresis, t, north?} <- [
          {2.0, 3.0, false},
          {2.0, 7.0, true},
          {100.0, 7.0, false},
          {nil, 7.0, false}
        ] do
      {plan, _actions, state} =
        on_sensed_map(dir, :explore, {160, 80}, door_east(false), {1.0, 2.0, 0.0})

      assert plan.state == :moving
      assert {fx, _} = state.target
      assert fx > 5.5

      {_, state} = Monitor.handle_param(:hysteresis, hysteresis, state)
      state = next_map(state, door_east(true))
      {plan, _, state} = cycle(state, t)
      assert plan.state == :moving
      {nx, ny} = state.target
      assert north? == (nx < 4.0 and ny > 2.4)
      if not north?, do: assert(nx > 5.5)
    end
  end

  @tag :tmp_dir
  test "exploring: with area_gain, a nearer pocket of unknown space loses to a door", %{
    tmp_dir: dir
  } do
    # the robot by a 0.4 x 0.4 m pocket of unknown space in the north-west
    # corner, 4.7 m from the door
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}
      if x < 0.5 and y > 3.5 and x > 0.05 and y < 3.95, do: -1, else: door_east(false).(c, r)
    end

    # with the area's gain, the door; without it (the default), the nearer one
    for {gain, door?} <- [{2.0, true}, {0.0, false}] do
      empty = Path.join(dir, "empty.wdf")
      File.write!(empty, "[name: \"nothing known\"]")
      data = for r <- 0..79, c <- 0..159, into: <<>>, do: <<cell.(c, r)::signed-8>>
      grid = ThinkingCap.Navigation.OccupancyGrid.new(160, 80, resolution: 0.05)
      {_, state} = Monitor.handle_param(:area_gain, gain, start(empty, :explore))
      {_, state} = Monitor.handle_tuple({:map, :r, %{grid | data: data, version: 1}}, state)
      {plan, _, state} = cycle(pose(state, {1.0, 3.0, 0.0}), 1.0)
      assert plan.state == :moving
      assert door? == elem(state.target, 0) > 5.5
      if not door?, do: assert(elem(state.target, 0) < 0.6)
    end
  end

  @tag :tmp_dir
  test "exploring on the sensed map gives no door to cross; going to a point does", %{
    tmp_dir: dir
  } do
    # 6 x 4 m walled round, a wall along x = 3 with a 1 m opening at y = 2,
    # unknown east of x = 5: the way to the frontier goes through it
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        x < 0.1 or y < 0.1 or x > 5.9 or y > 3.9 -> 100
        x >= 3.0 and x < 3.1 and abs(y - 2.0) > 0.5 -> 100
        x >= 5.0 -> -1
        true -> 0
      end
    end

    door = %{
      name: :door_1,
      centre: {3.05, 2.0},
      connects: [:room_1, :room_2],
      open: true,
      from: {3.05, 1.5},
      to: {3.05, 2.5}
    }

    topology = %ThinkingCap.Navigation.Topology{doors: %{door_1: door}}

    for {task, expected} <- [{:explore, nil}, {{:go_to, {4.5, 2.0}}, :door_1}] do
      {_plan, _actions, state} = on_sensed_map(dir, task, {120, 80}, cell, {1.0, 2.0, 0.0})
      {_, state} = Monitor.handle_tuple({:topology, :r, topology}, state)
      {plan, _actions, _state} = cycle(state, 1.5)
      assert plan.state == :moving
      assert (plan.door && plan.door.name) == expected
    end
  end

  @tag :tmp_dir
  test "exploring: a frontier in a nook is seen from a stand-in with room, not driven into", %{
    tmp_dir: dir
  } do
    # 6 x 4 m: a known room (x < 4) and, east of it, a nook 0.6 m wide and
    # 0.5 m deep whose far end is unknown: the one frontier, at x = 4.5.
    # The robot (0.2 m and its 0.08 m margin) fits in the nook only just.
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        x > 0.1 and x < 4.0 and y > 0.1 and y < 3.9 -> 0
        x >= 4.0 and x < 4.5 and abs(y - 2.0) < 0.3 -> 0
        x >= 4.5 and x < 5.5 and abs(y - 2.0) < 0.3 -> -1
        true -> 100
      end
    end

    {plan, _actions, state} = on_sensed_map(dir, :explore, {120, 80}, cell, {1.0, 2.0, 0.0})

    assert plan.state == :moving
    {fx, _fy} = state.target
    assert fx > 4.3 and fx < 4.6

    # the path ends short of the nook, within a metre of the frontier, at
    # a point with room round the robot (its radius, margin and 0.1 m)
    # that sees the frontier down the nook's axis
    {sx, sy} = List.last(plan.path)
    assert state.stand_in == {sx, sy}
    assert sx < 4.0 and fx - sx <= 1.05
    assert abs(sy - 2.0) < 0.15
    room = 0.2 + 0.08 + 0.1
    for corner <- [{4.0, 1.7}, {4.0, 2.3}], do: assert(dist({sx, sy}, corner) >= room - 0.03)
    refute Enum.any?(plan.path, fn {x, _y} -> x > 4.0 end)
  end

  @tag :tmp_dir
  test "exploring: a frontier just behind the robot is turned to before it counts as unseen",
       %{tmp_dir: dir} do
    # 4 x 4 m known and free but for an alcove west of the robot (at
    # {2, 2}, heading east), walled along y = 1.7 and 2.3 and unknown
    # inside: its frontier, 0.25 m behind the robot, is within reach
    cell = fn c, r ->
      {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

      cond do
        x < 0.1 or y < 0.1 or x > 3.9 or y > 3.9 -> 100
        x < 1.75 and abs(y - 2.0) < 0.3 -> -1
        x < 1.75 and abs(y - 2.0) < 0.4 -> 100
        true -> 0
      end
    end

    {plan, _actions, state} = on_sensed_map(dir, :explore, {80, 80}, cell, {2.0, 2.0, 0.0})
    {fx, fy} = state.target
    assert fx < 2.0 and abs(fy - 2.0) < 0.3
    assert dist({2.0, 2.0}, state.target) <= 0.35

    # not given up: the robot turns to it, driving to the frontier itself
    assert plan.state == :moving
    {plan, _, state} = cycle(state, 1.5)
    assert plan.state == :moving
    assert is_number(state.looking) and state.given_up == [] and state.target == {fx, fy}
    assert List.last(plan.path) == {fx, fy}
    {plan, _, state} = cycle(state, 2.0)
    assert plan.state == :moving and state.given_up == []

    # facing it, but on the map made before it turned (the mapper
    # publishes once a second): not judged yet
    assert state.rounds == 1
    map = state.map
    {plan, _, state} = cycle(pose(state, {2.0, 2.0, :math.pi()}), 3.0)
    assert plan.state == :moving and state.given_up == [] and state.rounds == 1

    # a map made since, the alcove still unknown: now it counts as unseen,
    # given up (the only frontier: tried again in a second round, anew)
    {_, state} = Monitor.handle_tuple({:map, :r, %{map | version: map.version + 1}}, state)
    {_plan, _, state} = cycle(state, 3.5)
    assert state.rounds == 2 and state.looking == nil

    # a robot that cannot turn to it (held, say) stops looking after 8 s:
    # then the frontier counts as unseen too
    {_plan, _, held} = on_sensed_map(dir, :explore, {80, 80}, cell, {2.0, 2.0, 0.0})
    {_plan, _, held} = cycle(held, 1.5)
    assert is_number(held.looking)
    {_plan, _, held} = cycle(held, 5.0)
    assert held.rounds == 1
    {_plan, _, held} = cycle(held, 10.0)
    assert held.rounds == 2

    # facing it from the start, with no map coming after (the map builder
    # gone quiet): it waits for one 8 s, then counts it as unseen
    {_plan, _, quiet} = on_sensed_map(dir, :explore, {80, 80}, cell, {2.0, 2.0, :math.pi()})
    {_plan, _, quiet} = cycle(quiet, 2.0)
    assert quiet.rounds == 1 and is_number(quiet.faced)
    {_plan, _, quiet} = cycle(quiet, 6.0)
    assert quiet.rounds == 1
    {_plan, _, quiet} = cycle(quiet, 11.0)
    assert quiet.rounds == 2
  end

  @tag :tmp_dir
  test "a doorway narrower than the margin allows is passed with the robot's own radius", %{
    tmp_dir: dir
  } do
    # 6 x 4 m, a wall along y = 2 with a 0.5 m gap: the robot (0.2 m)
    # fits, its margin (0.08 m each side) does not
    cell = fn c, r ->
      x = (c + 0.5) * 0.05
      if r == 40 and not (x > 2.74 and x < 3.24), do: 100, else: 0
    end

    {plan, _actions, _state} =
      on_sensed_map(dir, {:go_to, {3.0, 3.0}}, {120, 80}, cell, {3.0, 1.0, 1.57})

    assert plan.state == :moving
    assert Enum.any?(plan.path, fn {_x, y} -> y > 2.2 end)
  end

  test "plans through the office's doors to the waypoint and publishes the plan" do
    state = start(@office, {:go_to, :desk_a})
    {plan, _, state} = cycle(state, 0.0)
    assert plan.state == :waiting

    state = pose(state, {1.0, 1.0, 0.0})
    {plan, _, _state} = cycle(state, 0.5)
    assert plan.state == :moving
    assert plan.waypoint == :desk_a
    assert plan.goal == {10.0, 7.5}
    assert List.last(plan.path) == {10.0, 7.5}
    # through the door of office_a: the path crosses y = 3 between its jambs
    {{x1, _}, {x2, _}} =
      plan.path
      |> Enum.zip(tl(plan.path))
      |> Enum.find(fn {{_, a}, {_, b}} -> a < 3 and b >= 3 end)

    assert x1 > 9.0 and x1 < 10.0 and x2 > 9.0 and x2 < 10.0
    assert %{name: :a_door} = plan.door
  end

  test "a waypoint reached gives the next; a visit ends done" do
    state = start(@office, {:visit, [:dock, {1.5, 1.0}]})
    state = pose(state, {1.0, 1.0, 0.0})
    {plan, _, state} = cycle(state, 0.0)
    assert plan.waypoint == :dock
    # at the dock already: on to the next at the next cycle
    {plan, _, state} = cycle(state, 0.5)
    assert plan.waypoint == {1.5, 1.0}
    state = pose(state, {1.45, 1.0, 0.0})
    {plan, _, _state} = cycle(state, 1.0)
    assert plan.state == :done
    assert plan.reached == [:dock, {1.5, 1.0}]
  end

  defp tmp_wdf(dir, text) do
    path = Path.join(dir, "two_doors.wdf")
    File.write!(path, text)
    path
  end

  @tag :tmp_dir
  test "a door seen shut is marked closed and the route goes through the other", %{tmp_dir: dir} do
    state = start(tmp_wdf(dir, @two_doors), {:go_to, :desk})
    state = pose(state, {3.0, 1.5, :math.pi() / 2})
    {plan, _, state} = cycle(state, 0.0)
    assert %{name: :west} = plan.door

    # the laser sees something across the west door's opening, 1.5 m ahead
    state = lps(state, shut_ahead(1.5))
    {plan, actions, _state} = cycle(state, 0.5)
    assert {:out, {{:door, :west, %{open: false}}, _}} = List.keyfind(actions, :out, 0)
    assert :west in plan.closed_doors
    assert plan.state == :moving
    assert %{name: :east} = plan.door
    # the new path enters the room through the east door
    assert Enum.any?(plan.path, fn {x, y} -> x > 8.5 and x < 9.5 and abs(y - 3) < 0.3 end)
  end

  @tag :tmp_dir
  test "with every way in shut the goal is unreachable, then tried again", %{tmp_dir: dir} do
    text =
      String.replace(
        @two_doors,
        "[name: :east, from: {8.5, 3}, to: {9.5, 3}, connects: [:hall, :room]]",
        "[name: :east, from: {8.5, 3}, to: {9.5, 3}, open: false, connects: [:hall, :room]]"
      )

    state = start(tmp_wdf(dir, text), {:go_to, :desk})
    state = pose(state, {3.0, 1.5, :math.pi() / 2})
    {_plan, _, state} = cycle(state, 0.0)
    state = lps(state, shut_ahead(1.5))
    {plan, _, state} = cycle(state, 0.5)
    assert plan.state == :unreachable
    assert plan.reason =~ "no path to :desk"
    # the door opens again; after retry_after the planner tries again
    state = lps(state, LPS.empty())
    {plan, _, _state} = cycle(state, 11.0)
    assert plan.state == :moving
  end

  @tag :tmp_dir
  test "after no progress, the new plan keeps off a narrow gap for a wide one farther off", %{
    tmp_dir: dir
  } do
    # 6 x 4 m, a wall along y = 2 with a 0.6 m gap straight ahead (the
    # robot fits with its margin, by 2 cm) and a 1.2 m gap 2 m to the west
    cell = fn c, r ->
      x = (c + 0.5) * 0.05
      gap? = (x > 2.7 and x < 3.3) or (x > 0.4 and x < 1.6)
      if r == 40 and not gap?, do: 100, else: 0
    end

    crossing = fn plan ->
      plan.path |> Enum.min_by(fn {_x, y} -> abs(y - 2.0) end) |> elem(0)
    end

    {plan, _actions, state} =
      on_sensed_map(dir, {:go_to, {3.0, 3.0}}, {120, 80}, cell, {3.0, 1.0, 1.57})

    assert plan.state == :moving and abs(crossing.(plan) - 3.0) < 0.2

    # the robot stays where it is: 12 s later, a new plan by the wide gap
    {plan, _, state} =
      Enum.reduce(1..30, {plan, nil, state}, fn i, {_, _, state} ->
        cycle(state, 1.0 + i * 0.5)
      end)

    assert plan.replans == 1
    assert crossing.(plan) > 0.4 and crossing.(plan) < 1.6

    # a new waypoint is planned without the band: by the narrow gap again
    {_, state} = Monitor.handle_tuple({:task, :r, %{task: {:go_to, {3.0, 3.2}}}}, state)
    {plan, _, _state} = cycle(state, 17.0)
    assert abs(crossing.(plan) - 3.0) < 0.2
  end

  test "a robot that makes no progress gets a new plan, then gives the waypoint up" do
    state = start(@office, {:visit, [:desk_a, :dock]})
    state = pose(state, {5.0, 1.0, 0.0})
    {first, _, state} = cycle(state, 0.0)
    assert first.recoveries == 0

    {plans, _state} =
      Enum.map_reduce(1..100, state, fn i, state ->
        {plan, _, state} = cycle(state, i * 0.5)
        {plan, state}
      end)

    # 50 s without moving: three replans (every 12 s), then desk_a given up
    plan = List.last(plans)
    assert plan.waypoint == :dock
    assert plan.reached == []
    assert plan.given_up == [:desk_a]
    assert plan.state == :moving

    # each time it found the robot stuck it asked for a back-off: the
    # recoveries count rose with each replan and at the giving up, and
    # never fell (it counts over the run, not the waypoint)
    rises = plans |> Enum.map(& &1.recoveries) |> Enum.dedup()
    assert rises == [0, 1, 2, 3, 4]
    assert Enum.find(plans, &(&1.recoveries == 1)).replans == 1
  end

  @tag :tmp_dir
  test "a route that first leads away from the target is progress, not a robot stuck", %{
    tmp_dir: dir
  } do
    # in the room, the hall's point straight south behind the wall: the way
    # round through a door first takes the robot further from it
    state = start(tmp_wdf(dir, @two_doors), {:go_to, {6.0, 1.0}})
    state = pose(state, {6.0, 4.2, 0.0})
    {plan, _, state} = cycle(state, 0.0)
    path = plan.path
    length = path_length(path)
    assert length > 6.5

    # at 0.1 m/s along the path: the straight distance grows for ~30 s
    {plan, state} =
      Enum.reduce_while(1..400, {plan, state}, fn i, {_plan, state} ->
        state = pose(state, point_along(path, min(i * 0.05, length)))
        {plan, _, state} = cycle(state, i * 0.5)
        if plan.state == :moving, do: {:cont, {plan, state}}, else: {:halt, {plan, state}}
      end)

    assert plan.state == :done
    assert plan.given_up == []
    assert plan.replans == 0
    _ = state
  end

  defp path_length(path),
    do: path |> Enum.zip(tl(path)) |> Enum.map(fn {a, b} -> dist(a, b) end) |> Enum.sum()

  defp point_along([{x, y}], _s), do: {x, y, 0.0}

  defp point_along([a, b | rest], s) do
    l = dist(a, b)

    if s <= l do
      {ax, ay} = a
      {bx, by} = b
      t = if l > 0, do: s / l, else: 0.0
      {ax + (bx - ax) * t, ay + (by - ay) * t, 0.0}
    else
      point_along([b | rest], s - l)
    end
  end

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)

  test "after a failover it goes on with its task where it stood" do
    state = start(@office, {:visit, [:dock, :lab_bench, :desk_a]})
    state = pose(state, {1.0, 1.0, 0.0})
    # the dock reached, on the way to the lab bench
    {_plan, _, state} = cycle(state, 0.0)
    {plan, _, state} = cycle(state, 0.5)
    assert plan.waypoint == :lab_bench
    handoff = Monitor.handoff(state)

    resumed = start(@office, {:visit, [:dock, :lab_bench, :desk_a]}, handoff)
    {plan, _, resumed} = cycle(resumed, 1.0)
    assert plan.state == :waiting
    resumed = pose(resumed, {2.0, 1.5, 0.0})
    {plan, _, _} = cycle(resumed, 1.5)
    assert plan.state == :moving
    assert plan.waypoint == :lab_bench
    assert plan.reached == [:dock]
    assert List.last(plan.path) == {3.5, 7.0}
  end

  test "a task that gave up a waypoint ends failed, not done" do
    state = start(@office, {:go_to, :desk_a})
    state = pose(state, {5.0, 1.0, 0.0})
    {_plan, _, state} = cycle(state, 0.0)

    {plan, _, _state} =
      Enum.reduce(1..100, {nil, nil, state}, fn i, {_, _, state} -> cycle(state, i * 0.5) end)

    assert plan.state == :failed
    assert plan.given_up == [:desk_a]
    assert plan.reached == []
  end
end
