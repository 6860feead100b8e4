defmodule ThinkingCap.Navigation.PathPlannerTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{AStar, Grid, OccupancyGrid, PathPlanner}

  # a 10 x 6 m room at 5 cm: walls around it, free inside; `boxes` as
  # {x0, y0, x1, y1} occupied; the rest of the frame unknown
  defp room(version, boxes \\ [], opts \\ []) do
    {w, h} = {200, 120}
    unknown_from = Keyword.get(opts, :unknown_from, 10.0)

    data =
      for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>> do
        {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

        cond do
          c == 0 or r == 0 or c == w - 1 or r == h - 1 ->
            <<100>>

          Enum.any?(boxes, fn {x0, y0, x1, y1} -> x >= x0 and x <= x1 and y >= y0 and y <= y1 end) ->
            <<100>>

          x > unknown_from ->
            <<-1::signed-8>>

          true ->
            <<0>>
        end
      end

    %OccupancyGrid{width: w, height: h, data: data, resolution: 0.05, version: version}
  end

  defp length_of(points),
    do:
      points
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.map(fn [{ax, ay}, {bx, by}] -> :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2) end)
      |> Enum.sum()

  test "plans on the map, the obstacles grown by the robot's radius" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    assert {:ok, path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})
    assert planner.last.kind == :initial
    assert_in_delta length_of(path), 8.0, 0.1
    # no point of the path nearer than 0.3 m to the walls
    assert Enum.all?(path, fn {x, y} -> x >= 0.3 and y >= 0.3 and x <= 9.7 and y <= 5.7 end)
  end

  test "with a cost band, a plan takes the wide gap over the narrow, slightly shorter one" do
    # a wall across the room at x = 5: a 0.7 m gap on the straight line,
    # a 1.6 m one 1.5 m off it
    wall = [{4.95, 0.0, 5.05, 2.65}, {4.95, 3.35, 5.05, 3.7}, {4.95, 5.3, 5.05, 6.0}]
    crossing = fn path -> path |> Enum.min_by(fn {x, _} -> abs(x - 5.0) end) |> elem(1) end

    plain = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1, wall))
    assert {:ok, path, _} = PathPlanner.plan(plain, {2.0, 3.0}, {8.0, 3.0})
    assert crossing.(path) > 2.65 and crossing.(path) < 3.35

    banded = PathPlanner.new(radius: 0.3, band: 0.3) |> PathPlanner.set_map(room(1, wall))
    assert {:ok, path, _} = PathPlanner.plan(banded, {2.0, 3.0}, {8.0, 3.0})
    assert crossing.(path) > 3.7 and crossing.(path) < 5.3

    # the band: the cost falls from the grown obstacle's edge outwards,
    # none beyond the band; blocked cells as without it
    cost = fn planner, x -> :binary.at(planner.grid.cells, 60 * 200 + floor(x / 0.05)) end
    costs = Enum.map([0.38, 0.43, 0.48, 0.53], &cost.(banded, &1))
    assert costs == Enum.sort(costs, :desc) and length(Enum.uniq(costs)) == 4
    assert hd(costs) in 100..200 and List.last(costs) in 2..60
    assert cost.(banded, 0.68) == 0
    assert cost.(banded, 0.3) == 1 and cost.(plain, 0.3) == 1
    assert cost.(plain, 0.38) == 0
    assert_raise ArgumentError, ~r/band_cost/, fn -> PathPlanner.new(band_cost: 300) end
    assert_raise ArgumentError, ~r/band/, fn -> PathPlanner.new(band: -0.1) end
  end

  test "a box that appears on the path is planned around by repair, as A* from scratch would" do
    planner = PathPlanner.new(radius: 0.3, compare: true) |> PathPlanner.set_map(room(1))
    {:ok, _path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})

    # the robot moved on 1 m; a box now blocks the way ahead
    planner = PathPlanner.set_map(planner, room(2, [{4.5, 2.0, 5.5, 4.5}]))
    assert {:ok, path, planner} = PathPlanner.plan(planner, {2.0, 3.0}, {9.0, 3.0})
    assert planner.last.kind == :repair
    assert planner.last.changed > 0
    assert is_integer(planner.last.astar_us)
    assert is_integer(planner.last.cpu_us) and planner.last.cpu_us >= 0
    assert is_integer(planner.last.astar_cpu_us) and planner.last.astar_cpu_us >= 0

    # a box that appears away from the path costs the repair next to
    # nothing, where a search from scratch would search the whole way again
    boxes = [{4.5, 2.0, 5.5, 4.5}, {8.5, 0.1, 9.5, 0.6}]
    planner = PathPlanner.set_map(planner, room(3, boxes))
    assert {:ok, again, planner} = PathPlanner.plan(planner, {2.0, 3.0}, {9.0, 3.0})
    assert again == path
    assert planner.last.kind == :repair and planner.last.changed > 0
    fresh = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(3, boxes))
    {:ok, ^path, fresh} = PathPlanner.plan(fresh, {2.0, 3.0}, {9.0, 3.0})
    assert planner.last.expanded * 20 < fresh.last.expanded

    # around the box, at the robot's radius from it (within a cell)
    assert Enum.all?(path, fn {x, y} ->
             {dx, dy} = {max(0, max(4.5 - x, x - 5.5)), max(0, max(2.0 - y, y - 4.5))}
             :math.sqrt(dx * dx + dy * dy) >= 0.25
           end)

    # as short as A* finds on the same grid
    grid = planner.grid

    {:ok, %{cost: cost}} =
      AStar.plan(grid, Grid.cell_of(grid, {2.0, 3.0}), Grid.cell_of(grid, {9.0, 3.0}))

    assert_in_delta length_of(path), cost * grid.resolution, 0.05
  end

  test "maps that come between two plans, boxes appearing and going, are all repaired (20 seeds)" do
    for seed <- 1..20 do
      :rand.seed(:exsss, {seed, 3, 7})
      planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
      {:ok, _path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})

      box = fn ->
        {x, y} = {2.0 + 6 * :rand.uniform(), 0.5 + 5 * :rand.uniform()}
        {x, y, x + 0.2 + 0.6 * :rand.uniform(), y + 0.2 + 0.6 * :rand.uniform()}
      end

      # three plans, each after one to three maps; a box stays, goes or
      # comes with each map
      Enum.reduce(1..3, {planner, [], 2}, fn _, {planner, boxes, version} ->
        {planner, boxes, version} =
          Enum.reduce(1..:rand.uniform(3), {planner, boxes, version}, fn _, {p, bs, v} ->
            bs = Enum.filter(bs, fn _ -> :rand.uniform() < 0.6 end) ++ [box.()]
            {PathPlanner.set_map(p, room(v, bs)), bs, v + 1}
          end)

        case PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0}) do
          {:ok, path, planner} ->
            assert planner.last.kind in [:repair, :restart]
            grid = planner.grid

            {:ok, %{cost: cost}} =
              AStar.plan(
                grid,
                hd(path) |> then(&Grid.cell_of(grid, &1)),
                Grid.cell_of(grid, {9.0, 3.0})
              )

            assert_in_delta length_of(path), cost * grid.resolution, 1.0e-6, "seed #{seed}"
            {planner, boxes, version}

          {:error, reason, planner} ->
            fresh = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(version - 1, boxes))
            assert {:error, ^reason, _} = PathPlanner.plan(fresh, {1.0, 3.0}, {9.0, 3.0})
            {planner, boxes, version}
        end
      end)
    end
  end

  test "the same map seen again changes nothing; a new goal starts afresh" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    {:ok, _, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})
    assert PathPlanner.set_map(planner, room(1)) == planner
    {:ok, _, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {5.0, 5.0})
    assert planner.last.kind == :initial
  end

  test "a goal in unknown space is planned to; one off the map, in a wall or unreachable is an error" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1, [], unknown_from: 6.0))
    assert {:ok, path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {8.0, 3.0})
    assert List.last(path) |> elem(0) > 7.9

    assert {:error, :goal_outside_map, _} = PathPlanner.plan(planner, {1.0, 3.0}, {12.0, 3.0})
    assert {:error, :start_outside_map, _} = PathPlanner.plan(planner, {-3.0, 3.0}, {2.0, 3.0})
    assert {:error, :goal_blocked, _} = PathPlanner.plan(planner, {1.0, 3.0}, {0.02, 3.0})

    # a wall across the room: the east half cannot be reached
    walled = PathPlanner.set_map(planner, room(2, [{4.9, 0.0, 5.1, 6.0}]))
    assert {:error, :no_path, _} = PathPlanner.plan(walled, {1.0, 3.0}, {8.0, 3.0})
    assert {:error, :no_map, _} = PathPlanner.plan(PathPlanner.new(), {1.0, 3.0}, {2.0, 3.0})
  end

  test "a robot brushing a wall plans from the nearest free cell" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    assert {:ok, [first | _], _} = PathPlanner.plan(planner, {0.15, 3.0}, {5.0, 3.0})
    assert elem(first, 0) >= 0.3
  end

  test "big maps are planned on coarser cells" do
    planner = PathPlanner.new(radius: 0.3, resolution: 0.1) |> PathPlanner.set_map(room(1))
    assert {planner.grid.width, planner.grid.height, planner.grid.resolution} == {100, 60, 0.1}
    assert {:ok, path, _} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})
    assert_in_delta length_of(path), 8.0, 0.2
  end

  test "a repair counts the cells that changed; too many of them start a new search" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    {:ok, _path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})
    before = planner.grid

    boxed = PathPlanner.set_map(planner, room(2, [{4.5, 2.0, 5.5, 4.5}]))
    {:ok, path, boxed} = PathPlanner.plan(boxed, {1.5, 3.0}, {9.0, 3.0})
    differ = count_differences(before.cells, boxed.grid.cells)
    assert differ > 100
    assert boxed.last.kind == :repair and boxed.last.changed == differ

    # the same, allowed fewer changes than that: searched from scratch
    # (and the same path)
    few = PathPlanner.new(radius: 0.3, max_changes: differ - 1) |> PathPlanner.set_map(room(1))
    {:ok, _path, few} = PathPlanner.plan(few, {1.0, 3.0}, {9.0, 3.0})
    few = PathPlanner.set_map(few, room(2, [{4.5, 2.0, 5.5, 4.5}]))
    assert {:ok, ^path, few} = PathPlanner.plan(few, {1.5, 3.0}, {9.0, 3.0})
    assert few.last.kind == :restart

    # the box gone again: repaired back
    clear = PathPlanner.set_map(boxed, room(3))
    assert {:ok, _path, clear} = PathPlanner.plan(clear, {1.5, 3.0}, {9.0, 3.0})
    assert clear.last.kind == :repair and clear.last.changed == differ
  end

  test "a start that jumped (a robot found elsewhere) is repaired, as a search from scratch finds" do
    planner = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    {:ok, _path, planner} = PathPlanner.plan(planner, {1.0, 3.0}, {9.0, 3.0})

    # a step on: repaired
    {:ok, _path, stepped} = PathPlanner.plan(planner, {1.5, 3.0}, {9.0, 3.0})
    assert stepped.last.kind == :repair

    # 2 m further in one go (more than max_jump, 1.5 m): repaired, recorded
    # as a jump, with the cost of the path a search from scratch finds
    assert {:ok, path, jumped} = PathPlanner.plan(stepped, {3.5, 1.0}, {9.0, 3.0})
    assert jumped.last.kind == :jump
    fresh = PathPlanner.new(radius: 0.3) |> PathPlanner.set_map(room(1))
    assert {:ok, fresh_path, fresh} = PathPlanner.plan(fresh, {3.5, 1.0}, {9.0, 3.0})
    assert hd(path) == hd(fresh_path) and List.last(path) == List.last(fresh_path)
    assert_in_delta length_of(path), length_of(fresh_path), 1.0e-9
    # the distances to the goal it knew are not searched again
    assert jumped.last.expanded < fresh.last.expanded

    # allowed a longer jump, the same move is an ordinary repair
    far = PathPlanner.new(radius: 0.3, max_jump: 3.0) |> PathPlanner.set_map(room(1))
    {:ok, _path, far} = PathPlanner.plan(far, {1.5, 3.0}, {9.0, 3.0})
    assert {:ok, _path, far} = PathPlanner.plan(far, {3.5, 1.0}, {9.0, 3.0})
    assert far.last.kind == :repair
  end

  defp count_differences(a, b),
    do:
      Enum.zip(:binary.bin_to_list(a), :binary.bin_to_list(b))
      |> Enum.count(fn {x, y} -> x != y end)
end
