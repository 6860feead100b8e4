defmodule ThinkingCap.Navigation.Maps.SensedGridTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}
  alias ThinkingCap.Navigation.Maps.SensedGrid

  # A 360-beam laser at `{x, y}` inside the box {0, 0}-{4, 3}, with a box
  # (pillar) of half-width `pillar` at {3, 1.5} when given: exact ranges.
  defp scan({x, y}, opts \\ []) do
    n = 360
    inc = 2 * :math.pi() / n

    ranges =
      for i <- 0..(n - 1) do
        a = -:math.pi() + i * inc
        walls = box_range({x, y}, a, {0.0, 0.0, 4.0, 3.0}, :inside)

        case opts[:pillar] do
          nil -> walls
          h -> min(walls, box_range({x, y}, a, {3.0 - h, 1.5 - h, 3.0 + h, 1.5 + h}, :outside))
        end
      end

    %{
      ranges: ranges,
      angle_min: -:math.pi(),
      angle_increment: inc,
      range_min: 0.05,
      range_max: 8.0
    }
  end

  # distance along direction `a` to the box's boundary (slab method)
  defp box_range({x, y}, a, {x0, y0, x1, y1}, side) do
    {dx, dy} = {:math.cos(a), :math.sin(a)}

    t = fn p, d, lo, hi ->
      if abs(d) < 1.0e-12, do: {-1.0e18, 1.0e18}, else: order((lo - p) / d, (hi - p) / d)
    end

    {tx0, tx1} = t.(x, dx, x0, x1)
    {ty0, ty1} = t.(y, dy, y0, y1)
    {near, far} = {max(tx0, ty0), min(tx1, ty1)}

    case side do
      :inside -> far
      :outside -> if near <= far and near > 0, do: near, else: 100.0
    end
  end

  defp order(a, b), do: {min(a, b), max(a, b)}

  defp room_map, do: SensedGrid.new(100, 80, resolution: 0.05, origin: {-0.5, -0.5})

  defp cell(map, {x, y}),
    do: {floor((x - elem(map.origin, 0)) / 0.05), floor((y - elem(map.origin, 1)) / 0.05)}

  test "a scan makes the walls occupied, the room empty and the rest unknown" do
    map = room_map()
    for _ <- 1..3, do: SensedGrid.add_laser(map, scan({1.0, 1.0}), {1.0, 1.0, 0.0})

    # inside: empty, not occupied
    {e, o} = SensedGrid.degrees(map, cell(map, {2.0, 1.5}))
    assert e > 0.5 and o < 0.05
    # just beyond the east wall at x = 4 (the echo's cell): occupied, not empty
    {e, o} = SensedGrid.degrees(map, cell(map, {4.01, 1.0}))
    assert o > 0.6 and e < 0.1
    assert SensedGrid.occupied(map, cell(map, {4.01, 1.0})) > 0.6
    # outside the room: never seen
    assert SensedGrid.degrees(map, cell(map, {4.3, 1.0})) == {0.0, 0.0}

    occupancy = SensedGrid.occupancy(map, crop: false)
    assert OccupancyGrid.value(occupancy, cell(map, {4.3, 1.0})) == -1
    assert OccupancyGrid.value(occupancy, cell(map, {2.0, 1.5})) == 0
    assert OccupancyGrid.value(occupancy, cell(map, {4.01, 1.0})) >= 60
  end

  test "far readings count less than near ones" do
    map = room_map()
    SensedGrid.add_laser(map, scan({0.5, 1.5}), {0.5, 1.5, 0.0})
    {_, near} = SensedGrid.degrees(map, cell(map, {-0.01, 1.5}))
    {_, far} = SensedGrid.degrees(map, cell(map, {4.01, 1.5}))
    assert near > far and far > 0
  end

  test "evidence builds up, and an obstacle that left fades out of the map" do
    map = room_map()
    pillar = cell(map, {2.76, 1.5})

    for _ <- 1..5, do: SensedGrid.add_laser(map, scan({1.0, 1.5}, pillar: 0.25), {1.0, 1.5, 0.0})
    assert SensedGrid.occupied(map, pillar) > 0.8
    grid = OccupancyGrid.to_grid(SensedGrid.occupancy(map, crop: false), unknown: :free)
    refute Grid.passable?(grid, pillar)

    # the pillar is moved away: a few scans later its cells are free again
    occupied =
      for _ <- 1..10 do
        SensedGrid.add_laser(map, scan({1.0, 1.5}), {1.0, 1.5, 0.0})
        SensedGrid.occupied(map, pillar)
      end

    assert Enum.at(occupied, 0) < 0.8
    assert List.last(occupied) < 0.1
    assert occupied == Enum.sort(occupied, :desc)
    grid = OccupancyGrid.to_grid(SensedGrid.occupancy(map, crop: false), unknown: :free)
    assert Grid.passable?(grid, pillar)
  end

  test "a seeded map believes its prior until the sensors say otherwise" do
    prior = %{OccupancyGrid.new(100, 80, resolution: 0.05, origin: {-0.5, -0.5}) | version: 0}
    # a wall drawn where there is none: across the room at x = 2
    data =
      for _r <- 0..79, c <- 0..99, into: <<>> do
        <<if(c == 50, do: 100, else: 0)::signed-8>>
      end

    map = SensedGrid.seeded(%{prior | data: data}, 0.7)
    wall = {50, 30}
    {e, o} = SensedGrid.degrees(map, wall)
    assert e == 0.0
    assert_in_delta o, 0.7, 1.0e-4
    assert_in_delta elem(SensedGrid.degrees(map, {20, 30}), 0), 0.7, 1.0e-4

    for _ <- 1..10, do: SensedGrid.add_laser(map, scan({1.0, 1.0}), {1.0, 1.0, 0.0})
    assert SensedGrid.occupied(map, wall) < 0.2
  end

  test "the ground under the robot's footprint is empty, and nothing beyond it" do
    map = SensedGrid.new(40, 40, resolution: 0.05)
    # a round robot of radius 0.2 at {1.0, 1.0}: its cell (20, 20)
    assert SensedGrid.degrees(map, {20, 20}) == {0.0, 0.0}
    SensedGrid.add_footprint(map, {1.0, 1.0, 0.0}, [{0.0, 0.0, 0.2}])
    {e, o} = SensedGrid.degrees(map, {20, 20})
    assert e > 0.25 and o == 0.0
    # 0.3 m away: outside the footprint, still unknown
    assert SensedGrid.degrees(map, {26, 20}) == {0.0, 0.0}
  end

  test "a sonar cone empties its inside and marks an arc at its echo" do
    map = room_map()
    ring = %{pose: {0.0, 0.0, 0.0}, ring_radius: 0.0, fov: 0.3}
    # one transducer facing the east wall, 3 m away
    reading = %{ranges: [3.0], headings: [0.0], range_max: 5.0}
    map = %{map | sonar: %{map.sonar | trust: 5.0}}
    for _ <- 1..3, do: SensedGrid.add_sonar(map, reading, {1.0, 1.5, 0.0}, ring)
    assert elem(SensedGrid.degrees(map, cell(map, {2.5, 1.5})), 0) > 0.2
    # the arc: across the cone at 3 m, beside the axis too
    assert elem(SensedGrid.degrees(map, cell(map, {4.01, 1.5})), 1) > 0.2
    assert elem(SensedGrid.degrees(map, cell(map, {4.01, 1.8})), 1) > 0.2
    # nothing behind the transducer
    assert SensedGrid.degrees(map, cell(map, {0.5, 1.5})) == {0.0, 0.0}
  end

  test "the observed box, cropping and a round trip through export and import" do
    map = room_map()
    assert SensedGrid.observed_box(map) == nil
    SensedGrid.add_laser(map, scan({1.0, 1.0}), {1.0, 1.0, 0.0})
    {c0, r0, c1, r1} = SensedGrid.observed_box(map)
    # the echoes' cells lie just beyond the walls
    assert {c0, r0} == cell(map, {-0.01, -0.01}) and {c1, r1} == cell(map, {4.01, 3.01})

    cropped = SensedGrid.occupancy(map, pad: 2)
    assert cropped.width == c1 - c0 + 5 and cropped.height == r1 - r0 + 5
    {ox, oy} = cropped.origin
    assert_in_delta ox, -0.5 + (c0 - 2) * 0.05, 1.0e-9
    assert_in_delta oy, -0.5 + (r0 - 2) * 0.05, 1.0e-9

    copy = room_map()
    assert :ok = SensedGrid.import(copy, SensedGrid.export(map))

    assert SensedGrid.occupancy(copy, crop: false).data ==
             SensedGrid.occupancy(map, crop: false).data

    assert {:error, _} = SensedGrid.import(copy, <<1, 2, 3>>)
  end
end
