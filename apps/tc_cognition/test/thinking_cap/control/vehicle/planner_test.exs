defmodule ThinkingCap.Control.Vehicle.PlannerTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.Vehicle.{Planner, Tracker}
  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Robot.Kinematics
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  # a 12 m x 8 m room at 0.1 m, walls one cell thick, `blocked` cells added
  defp room(blocked \\ []) do
    {w, h} = {120, 80}

    walls = for c <- 0..(w - 1), r <- 0..(h - 1), c in [0, w - 1] or r in [0, h - 1], do: {c, r}

    Grid.new(w, h, resolution: 0.1) |> Grid.put(walls ++ blocked, true)
  end

  defp poses(segments), do: Enum.flat_map(segments, & &1.poses)

  # consecutive poses turn no tighter than the curvature allows
  defp assert_feasible(start, segments, k) do
    Enum.reduce(poses(segments), start, fn {x, y, th} = p, {px, py, pth} ->
      ds = :math.sqrt((x - px) ** 2 + (y - py) ** 2)
      dth = abs(normalize_angle(th - pth))
      # (ds is the chord, a little shorter than the arc)
      assert dth <= k * ds * 1.01 + 1.0e-6
      p
    end)
  end

  test "a path to a pose behind the robot turns within the steering limit and ends on the goal" do
    grid = room()
    k = 1.0
    start = {3.0, 4.0, 0.0}
    goal = {2.0, 4.0, :math.pi()}
    assert {:ok, segments} = Planner.plan(grid, start, goal, max_curvature: k)
    assert_feasible(start, segments, k)

    {x, y, th} = segments |> poses() |> List.last()
    assert :math.sqrt((x - 2.0) ** 2 + (y - 4.0) ** 2) <= 0.2
    assert abs(normalize_angle(th - :math.pi())) <= 0.15

    for {px, py, _} <- poses(segments),
        do: assert(Grid.passable?(grid, Grid.cell_of(grid, {px, py})))
  end

  test "in a narrow corridor it turns round in several moves, forwards and in reverse" do
    # a corridor 2.4 m wide: a 1.5 m turning radius needs 3 m to turn round at once
    blocked = for c <- 0..119, r <- 0..79, r < 28 or r > 52, do: {c, r}
    grid = room(blocked)
    k = 1 / 1.5
    start = {6.0, 4.0, 0.0}
    assert {:ok, segments} = Planner.plan(grid, start, {4.0, 4.0, :math.pi()}, max_curvature: k)
    assert_feasible(start, segments, k)
    assert -1 in Enum.map(segments, & &1.direction)
    assert length(segments) >= 2
  end

  test "without reversing, the same turn is impossible" do
    blocked = for c <- 0..119, r <- 0..79, r < 28 or r > 52, do: {c, r}
    grid = room(blocked)

    assert {:error, reason} =
             Planner.plan(grid, {6.0, 4.0, 0.0}, {4.0, 4.0, :math.pi()},
               max_curvature: 1 / 1.5,
               reverse: false,
               max_expansions: 5_000
             )

    assert reason in [:unreachable, :too_hard]
  end

  test "a goal line: any pose on it with the goal's heading will do" do
    grid = room()
    line = {{6.0, 4.0}, {9.0, 4.0}, 0.1}

    assert {:ok, segments} =
             Planner.plan(grid, {2.0, 2.0, :math.pi()}, {6.0, 4.0, :math.pi()},
               max_curvature: 1.0,
               line: line
             )

    {x, y, th} = segments |> poses() |> List.last()
    assert x >= 5.8 and x <= 9.2
    assert abs(y - 4.0) <= 0.2
    assert abs(normalize_angle(th - :math.pi())) <= 0.15
  end

  test "blocked starts and goals and walled-off goals are errors" do
    wall = for r <- 0..79, c <- 58..61, do: {c, r}
    grid = room(wall)

    assert {:error, :start_blocked} =
             Planner.plan(grid, {0.0, 0.0, 0.0}, {3.0, 3.0, nil}, max_curvature: 1.0)

    assert {:error, :goal_blocked} =
             Planner.plan(grid, {3.0, 3.0, 0.0}, {6.0, 3.0, nil}, max_curvature: 1.0)

    assert {:error, :unreachable} =
             Planner.plan(grid, {3.0, 3.0, 0.0}, {9.0, 3.0, nil}, max_curvature: 1.0)
  end

  describe "tracker" do
    # drives the kinematic model along the tracker's commands
    defp follow(tracker, pose, opts, steps) do
      Enum.reduce_while(1..steps, {tracker, pose, []}, fn _, {t, p, speeds} ->
        case Tracker.step(t, p, opts) do
          {:done, t} -> {:halt, {:done, t, p, speeds}}
          {:drive, {v, w}, t} -> {:cont, {t, Kinematics.integrate(p, {v, w}, 0.1), [v | speeds]}}
        end
      end)
    end

    @opts [
      max_curvature: 1.0,
      max_speed: 0.8,
      final_speed: 0.2,
      max_turn_rate: 1.0,
      lookahead: 0.8
    ]

    test "converges on a straight line and stops at its end, forwards and in reverse" do
      line = for i <- 0..60, do: {i * 0.1, 0.0}

      for {direction, start} <- [{1, {0.0, 0.3, 0.2}}, {-1, {0.0, 0.3, :math.pi() - 0.2}}] do
        t = Tracker.new([%{direction: direction, points: line}])
        assert {:done, _t, {x, y, th}, speeds} = follow(t, start, @opts, 400)
        assert abs(x - 6.0) < 0.05
        assert abs(y) < 0.03
        heading = if direction == 1, do: 0.0, else: :math.pi()
        assert abs(normalize_angle(th - heading)) < 0.05
        assert Enum.all?(speeds, &(&1 * direction >= 0))
        # slow at the end of the last segment
        assert abs(hd(speeds)) <= 0.2
      end
    end

    test "stops at a cusp and drives the next segment the other way" do
      out = for i <- 0..30, do: {i * 0.1, 0.0}
      back = for i <- 0..30, do: {3.0 - i * 0.1, 0.0}
      t = Tracker.new([%{direction: 1, points: out}, %{direction: -1, points: back}])
      assert {:done, _t, {x, _, _}, speeds} = follow(t, {0.0, 0.0, 0.0}, @opts, 600)
      assert abs(x) < 0.05
      assert Enum.any?(speeds, &(&1 > 0)) and Enum.any?(speeds, &(&1 < 0))
    end
  end
end
