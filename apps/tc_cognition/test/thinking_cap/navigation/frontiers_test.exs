defmodule ThinkingCap.Navigation.FrontiersTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Frontiers, OccupancyGrid, PathPlanner}

  # A 10 x 6 m frame at 5 cm, walled around. A wall along y = 3 m from
  # x = 2 m to the right end splits it; the gap x < 2 m joins the halves.
  # Seen free: the lower half up to x = 9.5 m, and the upper half up to
  # x = 6 m; the rest is unknown. Two frontiers: the upper half's at
  # x = 6 m, reached only round the wall, and the lower half's at 9.5 m.
  defp map do
    framed(fn x, y ->
      cond do
        y >= 3.0 and y < 3.1 and x >= 2.0 -> <<100>>
        y < 3.0 and x > 9.5 -> <<-1::signed-8>>
        y >= 3.1 and x > 6.0 -> <<-1::signed-8>>
        true -> <<0>>
      end
    end)
  end

  # a 10 x 6 m frame at 5 cm, walled around, each cell inside as
  # `inside.(x, y)` of its centre says
  defp framed(inside) do
    {w, h} = {200, 120}

    data =
      for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>> do
        if c == 0 or r == 0 or c == w - 1 or r == h - 1,
          do: <<100>>,
          else: inside.((c + 0.5) * 0.05, (r + 0.5) * 0.05)
      end

    %OccupancyGrid{width: w, height: h, data: data, resolution: 0.05, version: 1}
  end

  defp frontier_at(frontiers, x0),
    do: Enum.find(frontiers, fn %{point: {x, _}} -> abs(x - x0) < 0.15 end)

  test "finds the boundaries between seen free and unknown space" do
    frontiers = Frontiers.find(map())
    assert length(frontiers) == 2
    assert %{point: {_, y}} = frontier_at(frontiers, 6.0)
    assert y > 3.1
    assert %{point: {_, y}} = frontier_at(frontiers, 9.5)
    assert y < 3.0
  end

  test "by the straight line the frontier behind the wall wins; by the path the open one" do
    map = map()
    frontiers = Frontiers.find(map)
    behind = frontier_at(frontiers, 6.0)
    open = frontier_at(frontiers, 9.5)
    robot = {6.0, 2.5}

    assert Frontiers.choose(frontiers, robot, gain: 0.0) == behind

    planner = PathPlanner.new(radius: 0.25) |> PathPlanner.set_map(map)
    points = [behind.point, open.point]
    [round_the_wall, straight_on] = PathPlanner.distances(planner, robot, points)
    # round the wall's end at x = 2 m and back: more than 8 m
    assert round_the_wall > 8.0
    assert_in_delta straight_on, 3.5, 0.5

    distances = Map.new(Enum.zip(points, [round_the_wall, straight_on]))
    assert Frontiers.choose(frontiers, robot, gain: 0.0, distances: distances) == open
  end

  test "a frontier without a path is skipped; none reachable is none" do
    frontiers = Frontiers.find(map())
    behind = frontier_at(frontiers, 6.0)
    open = frontier_at(frontiers, 9.5)
    distances = %{behind.point => 1.0, open.point => nil}
    assert Frontiers.choose(frontiers, {9.0, 1.0}, distances: distances) == behind
    assert Frontiers.choose(frontiers, {9.0, 1.0}, distances: %{}) == nil
  end

  test "paths' lengths: nil off the map or in a wall; all nil from off the map or without one" do
    map = map()
    planner = PathPlanner.new(radius: 0.25) |> PathPlanner.set_map(map)

    [off, wall, here] =
      PathPlanner.distances(planner, {1.0, 1.0}, [{20.0, 1.0}, {5.0, 3.05}, {1.0, 1.0}])

    assert off == nil
    # in the wall, with no free cell within the radius
    assert wall == nil
    assert here == 0.0
    assert PathPlanner.distances(planner, {-3.0, 1.0}, [{1.0, 1.0}]) == [nil]
    assert PathPlanner.distances(PathPlanner.new(), {1.0, 1.0}, [{2.0, 1.0}]) == [nil]
  end

  test "a frontier remains while free cells border unknown ones near it, not unknown behind a wall" do
    map = map()
    # below the wall, the upper half unknown 0.25 m away behind it
    assert Frontiers.unknown_near?(map, {8.0, 2.9}, 0.5)
    refute Frontiers.remains?(map, {8.0, 2.9}, 0.5)
    # the lower half's frontier at x = 9.5 m, and the upper half's at 6 m
    assert Frontiers.remains?(map, {9.3, 1.0}, 0.5)
    assert Frontiers.remains?(map, {5.8, 4.0}, 0.5)
    # too short a piece of frontier within the radius is none
    refute Frontiers.remains?(map, {9.3, 1.0}, 0.5, min_length: 1.2)
  end

  # A 10 x 6 m frame at 5 cm, walled around, seen free west of x = 5 m.
  # A wall along x = 5 m with a door (y 2.5 to 3.5 m) into unknown space;
  # in the south-west corner, 0.6 x 0.6 m unknown behind a box's corner:
  # a pocket bounded by the outer walls.
  defp door_and_pocket do
    framed(fn x, y ->
      cond do
        x >= 5.0 and x < 5.1 and (y < 2.5 or y > 3.5) -> <<100>>
        x >= 5.0 -> <<-1::signed-8>>
        x < 0.65 and y < 0.65 -> <<-1::signed-8>>
        true -> <<0>>
      end
    end)
  end

  test "the unknown area a frontier opens onto: a door's room up to the cap, a pocket its own" do
    map = door_and_pocket()
    [door, pocket] = Enum.sort_by(Frontiers.find(map, area: true), fn %{point: {x, _}} -> -x end)
    assert_in_delta elem(door.point, 0), 4.95, 0.1
    assert door.area == Frontiers.unknown_area(map, door.point)
    # beyond the door: a half disc of 3 m, counted up to 6 m²
    assert_in_delta door.area, 6.0, 0.1
    assert_in_delta Frontiers.unknown_area(map, door.point, area_cap: 100.0), 14.1, 1.5
    # the pocket: 0.6 x 0.6 m, none of it leaking past the outer walls
    assert_in_delta pocket.area, 0.36, 0.08
    # a point in seen free space opens onto nothing
    assert Frontiers.unknown_area(map, {2.5, 3.0}) == 0.0
    # not asked for, the areas are not counted
    assert Enum.map(Frontiers.find(map), & &1.area) == [0.0, 0.0]
  end

  test "a pocket under min_area is dropped" do
    assert length(Frontiers.find(door_and_pocket())) == 2
    assert [%{point: {x, _}}] = Frontiers.find(door_and_pocket(), min_area: 0.5)
    assert x > 4.5
  end

  test "with area_gain, the door into unknown space wins over a nearer pocket" do
    frontiers = Frontiers.find(door_and_pocket(), area: true)
    robot = {1.5, 1.0}
    assert %{point: {x, _}} = Frontiers.choose(frontiers, robot)
    assert x < 1.0
    assert %{point: {x, _}} = Frontiers.choose(frontiers, robot, area_gain: 2.0)
    assert x > 4.5
    assert Frontiers.cost(%{length: 1.0, area: 3.0}, 10.0, area_gain: 2.0) == 3.0
  end
end
