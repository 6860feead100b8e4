defmodule ThinkingCap.Navigation.KeepClearTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{KeepClear, OccupancyGrid, PathPlanner}

  # a corridor 10 m long and 1.6 m wide (walls at y = 0 and y = 1.6),
  # with a room of 4 x 4 m above it reached through a 0.9 m door at x = 7
  defp building do
    {w, h} = {200, 120}

    data =
      for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>> do
        {x, y} = {(c + 0.5) * 0.05, (r + 0.5) * 0.05}

        wall =
          c == 0 or r == 0 or c == w - 1 or r == h - 1 or
            (abs(y - 1.6) < 0.05 and not (x > 6.55 and x < 7.45)) or
            (y > 1.6 and (x < 5.0 or x > 9.0))

        if wall, do: <<100>>, else: <<0>>
      end

    %OccupancyGrid{width: w, height: h, data: data, resolution: 0.05, version: 1}
  end

  defp planner(clearance),
    do: PathPlanner.new(radius: 0.28, clearance: clearance) |> PathPlanner.set_map(building())

  defp least_clearance(field, path) do
    path
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.flat_map(fn [{ax, ay}, {bx, by}] ->
      for i <- 0..20, do: {ax + i / 20 * (bx - ax), ay + i / 20 * (by - ay)}
    end)
    |> Enum.map(&KeepClear.clearance(field, &1))
    |> Enum.min()
  end

  test "a path along a corridor is moved to its middle, its ends kept" do
    # more than half the corridor's width: the middle is as far as it gets
    p = planner(1.0)
    # start and goal near the lower wall: the shortest path runs along it
    {:ok, path, p} = PathPlanner.plan(p, {0.5, 0.35}, {4.5, 0.35})
    assert Enum.all?(path, fn {_x, y} -> y < 0.45 end)

    pushed = PathPlanner.keep_clear(p, path)
    assert hd(pushed) == hd(path) and List.last(pushed) == List.last(path)
    assert length(pushed) == length(path)

    # the inner points far from the ends reach the corridor's middle
    # (0.8 m from both walls, within a cell)
    middle = pushed |> Enum.filter(fn {x, _} -> x > 1.5 and x < 3.5 end)
    assert middle != []
    assert Enum.all?(middle, fn {_x, y} -> abs(y - 0.8) <= 0.06 end)
    assert least_clearance(p.field, pushed) >= least_clearance(p.field, path) - 1.0e-9
  end

  test "a point already clear enough stays, and none moves more than it may" do
    p = planner(0.3)
    {:ok, path, p} = PathPlanner.plan(p, {0.5, 0.35}, {4.5, 0.35})
    pushed = PathPlanner.keep_clear(p, path)

    for {{x0, y0}, {x1, y1}} <- Enum.zip(path, pushed) do
      shift = :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
      assert shift <= 0.3 + 0.05
      # a point as far from the walls as wanted is not moved
      if KeepClear.clearance(p.field, {x0, y0}) >= 0.3, do: assert(shift == 0.0)
    end
  end

  test "through a door, the path keeps at least the clearance it had" do
    p = planner(0.7)
    {:ok, path, p} = PathPlanner.plan(p, {1.0, 0.8}, {7.0, 3.5})
    pushed = PathPlanner.keep_clear(p, path)
    before = least_clearance(p.field, path)
    assert least_clearance(p.field, pushed) >= min(before, 0.28) - 1.0e-9
    # the points by the door's jambs moved towards its centre line (x = 7)
    near_door = fn pts -> Enum.filter(pts, fn {_x, y} -> abs(y - 1.6) < 0.3 end) end

    assert Enum.sum(Enum.map(near_door.(pushed), fn {x, _} -> abs(x - 7.0) end)) <=
             Enum.sum(Enum.map(near_door.(path), fn {x, _} -> abs(x - 7.0) end))
  end

  test "without a clearance the path is left as planned" do
    p = planner(nil)
    {:ok, path, p} = PathPlanner.plan(p, {0.5, 0.35}, {4.5, 0.35})
    assert PathPlanner.keep_clear(p, path) == path
    # the distance field is kept all the same, for clearance/2
    assert PathPlanner.clearance(p, {2.5, 0.35}) > 0.0
  end
end
