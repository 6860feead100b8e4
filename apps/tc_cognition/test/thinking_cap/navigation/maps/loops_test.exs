defmodule ThinkingCap.Navigation.Maps.LoopsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Navigation.Maps.{Loops, SensedGrid}
  alias ThinkingCap.Test.DriftingCircle
  import ThinkingCap.Geometry, only: [normalize_angle: 1, segment_distance: 3]

  # a room of 8 x 6 m with a pillar: no symmetry makes two poses alike
  @walls [
    {{0.0, 0.0}, {8.0, 0.0}},
    {{8.0, 0.0}, {8.0, 6.0}},
    {{8.0, 6.0}, {0.0, 6.0}},
    {{0.0, 6.0}, {0.0, 0.0}},
    {{1.5, 1.0}, {2.0, 1.0}},
    {{2.0, 1.0}, {2.0, 1.8}},
    {{2.0, 1.8}, {1.5, 1.8}},
    {{1.5, 1.8}, {1.5, 1.0}}
  ]
  # a 180-degree laser scan from a pose, by casting rays at the walls
  defp scan(pose), do: ThinkingCap.Test.LaserRoom.scan(@walls, pose)

  # twice round the room's centre, the estimate turning 0.3 degrees a
  # step too far (10 degrees a turn)
  defp drive(loops) do
    DriftingCircle.drive(
      72,
      loops,
      fn true_pose, estimate, loops ->
        Loops.record(loops, :laser, {0.0, 0.0, 0.0}, scan(true_pose), estimate, nil)
      end,
      0.005
    )
  end

  defp grid, do: SensedGrid.new(200, 160, resolution: 0.05, origin: {-1.0, -1.0})

  # the share of the occupied cells within 10 cm of a wall
  defp on_walls(grid) do
    map = SensedGrid.occupancy(grid)

    {ox, oy} = map.origin

    cells =
      for r <- 0..(map.height - 1),
          c <- 0..(map.width - 1),
          OccupancyGrid.value(map, {c, r}) >= 65,
          do: {ox + (c + 0.5) * map.resolution, oy + (r + 0.5) * map.resolution}

    near =
      Enum.count(cells, fn p ->
        Enum.any?(@walls, fn {a, b} -> segment_distance(p, a, b) <= 0.1 end)
      end)

    {near / max(length(cells), 1), length(cells)}
  end

  # the graph's nodes at the estimates, the map moved only by loops
  @estimates_only [local_nodes: 0, follow_distance: 0.0]

  test "closing loops draws the walls where they are; without, the drift smears them" do
    {closing, closed} = drive(Loops.new([loop_gap: 15] ++ @estimates_only))
    assert closed > 0
    assert Loops.frame(closing) == closed

    {share, count} = on_walls(Loops.redraw(closing, grid(), %{laser: {0.0, 0.0, 0.0}}, []))
    assert share > 0.97 and count > 300

    # the same scans never matched: drawn where the drifting estimate put them
    {open, 0} = drive(Loops.new([loop_gap: 10_000] ++ @estimates_only))
    {smeared, _} = on_walls(Loops.redraw(open, grid(), %{laser: {0.0, 0.0, 0.0}}, []))
    assert smeared < share - 0.3
  end

  test "without loops, the chain of scan matches keeps the walls where they are" do
    # each scan matched against the last few: the map follows the chain,
    # moved under the drifting estimate whenever the two part
    {open, moves} = drive(Loops.new(loop_gap: 10_000))
    assert moves > 0
    {share, count} = on_walls(Loops.redraw(open, grid(), %{laser: {0.0, 0.0, 0.0}}, []))
    assert share > 0.97 and count > 300
  end

  test "SensedGrid.replay_lasers/5 draws kept scans as add_laser/3 does one by one" do
    poses = [{2.0, 2.0, 0.3}, {4.0, 3.0, 1.2}, {6.0, 4.5, -2.0}]
    one_by_one = grid()
    Enum.each(poses, &SensedGrid.add_laser(one_by_one, scan(&1), &1))

    at_once = grid()

    pose_bin =
      for {x, y, th} <- poses,
          into: <<>>,
          do: <<x::float-native, y::float-native, th::float-native>>

    ranges = for p <- poses, r <- scan(p).ranges, into: <<>>, do: <<r::float-32-native>>

    SensedGrid.replay_lasers(
      at_once,
      pose_bin,
      ranges,
      ThinkingCap.Test.LaserRoom.beams(),
      scan({0.0, 0.0, 0.0})
    )

    a = SensedGrid.occupancy(one_by_one)
    b = SensedGrid.occupancy(at_once)
    assert {a.width, a.height, a.origin} == {b.width, b.height, b.origin}

    differing =
      Enum.count(Enum.zip(:binary.bin_to_list(a.data), :binary.bin_to_list(b.data)), fn {x, y} ->
        x != y
      end)

    # 32-bit ranges may move an endpoint across a cell boundary, rarely
    assert differing <= 5
    assert Enum.count(:binary.bin_to_list(a.data), &(&1 != 255)) > 1000
  end

  test "carry/3 brings an estimate of the frame before into the current one" do
    {loops, closed} = drive(Loops.new(loop_gap: 15))
    current = Loops.frame(loops)
    assert current == closed
    pose = {1.0, 2.0, 0.3}
    assert Loops.carry(loops, pose, current) == pose
    {from, to} = loops.moves[current]
    assert Loops.carry(loops, from, current - 1) |> close_to(to)
    if current >= 2, do: assert(Loops.carry(loops, pose, current - 2) == nil)
  end

  defp close_to({x1, y1, t1}, {x2, y2, t2}),
    do: abs(x1 - x2) < 1.0e-9 and abs(y1 - y2) < 1.0e-9 and abs(normalize_angle(t1 - t2)) < 1.0e-9
end
