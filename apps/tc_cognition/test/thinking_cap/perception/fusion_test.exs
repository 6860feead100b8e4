defmodule ThinkingCap.Perception.FusionTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Perception.{Fusion, Lines, LPS}

  @laser %{type: :laser, pose: {0.0, 0.0, 0.0}, range: {0.05, 8.0}}
  @sonar %{
    type: :sonar,
    pose: {0.0, 0.0, 0.0},
    ring_radius: 0.1,
    count: 8,
    range: {0.05, 5.0},
    fov: 0.3
  }

  # a 181-beam scan (-90°..90°) of a wall x = d in front of a robot at the origin
  defp wall_scan(d, stamp, opts \\ []) do
    gap = Keyword.get(opts, :gap)

    ranges =
      for i <- 0..180 do
        a = -:math.pi() / 2 + i * :math.pi() / 180
        r = if :math.cos(a) > 1.0e-6, do: d / :math.cos(a), else: 8.0
        y = r * :math.sin(a)

        cond do
          r >= 8.0 -> 8.0
          gap && y > elem(gap, 0) && y < elem(gap, 1) -> 8.0
          true -> r
        end
      end

    %{ranges: ranges, angle_min: -:math.pi() / 2, angle_increment: :math.pi() / 180, stamp: stamp}
  end

  defp fusion(opts \\ []) do
    Fusion.new(%{laser: @laser, sonar: @sonar}, opts)
    |> Fusion.put_odometry({0.0, 0.0, 0.0}, 0.0)
  end

  test "a wall seen by the laser is in front at its distance, as a segment" do
    lps = fusion() |> Fusion.add_reading(:laser, wall_scan(2.0, 0.1)) |> Fusion.lps()
    assert_in_delta LPS.distance_at(lps, 0.0), 2.0, 0.1
    assert_in_delta LPS.min_distance(lps, -0.3, 0.3), 2.0, 0.1
    # behind: nothing
    assert LPS.min_distance(lps, 2.5, -2.5) == lps.range

    assert Enum.any?(lps.segments, fn {{x1, _}, {x2, _}} ->
             abs(x1 - 2.0) < 0.15 and abs(x2 - 2.0) < 0.15
           end)
  end

  test "the LPS follows the robot's odometry between readings" do
    f = fusion() |> Fusion.add_reading(:laser, wall_scan(2.0, 0.1))
    lps = f |> Fusion.put_odometry({0.5, 0.0, 0.0}, 0.2) |> Fusion.lps()
    assert_in_delta LPS.distance_at(lps, 0.0), 1.5, 0.1
    # turned left by 90°: the wall is now on the right
    lps = f |> Fusion.put_odometry({0.0, 0.0, :math.pi() / 2}, 0.2) |> Fusion.lps()
    assert_in_delta LPS.distance_at(lps, -:math.pi() / 2), 2.0, 0.1
    assert LPS.distance_at(lps, 0.0) == lps.range
  end

  test "an obstacle that went away is seen through and fades" do
    f = fusion() |> Fusion.add_reading(:laser, wall_scan(1.0, 0.1))
    assert_in_delta LPS.distance_at(Fusion.lps(f), 0.0), 1.0, 0.1
    # the obstacle moved: the same beams now reach a wall 4 m away
    lps = f |> Fusion.add_reading(:laser, wall_scan(4.0, 0.2)) |> Fusion.lps()
    assert_in_delta LPS.distance_at(lps, 0.0), 4.0, 0.1

    [{_, _, o, e} | _] =
      Enum.filter(lps.evidence, fn {x, y, _, _} -> abs(x - 1.0) < 0.1 and abs(y) < 0.1 end)

    assert o >= 0.9 and e >= 0.9
  end

  test "evidence not refreshed is forgotten after the memory" do
    f = fusion(memory: 1.0) |> Fusion.add_reading(:laser, wall_scan(2.0, 0.1))
    # 2 s later the sonar sees nothing anywhere: the laser's wall is stale
    lps =
      f
      |> Fusion.put_odometry({0.0, 0.0, 0.0}, 2.5)
      |> Fusion.add_reading(:sonar, %{ranges: List.duplicate(5.0, 8), stamp: 2.5})
      |> Fusion.lps()

    assert LPS.distance_at(lps, 0.0) == lps.range
    assert lps.evidence == []
  end

  test "sonar echoes count, less sure than laser hits" do
    ranges = [1.5 | List.duplicate(5.0, 7)]
    lps = fusion() |> Fusion.add_reading(:sonar, %{ranges: ranges, stamp: 0.1}) |> Fusion.lps()
    assert_in_delta LPS.distance_at(lps, 0.0), 1.6, 0.1
    [{_, _, o, _}] = lps.evidence
    assert o == 0.6
  end

  test "a door-wide gap between wall segments is an opening" do
    lps =
      fusion() |> Fusion.add_reading(:laser, wall_scan(2.0, 0.1, gap: {0.5, 1.4})) |> Fusion.lps()

    assert [%{centre: {cx, cy}, width: w}] = lps.doors
    assert_in_delta cx, 2.0, 0.15
    assert_in_delta cy, 0.95, 0.15
    assert_in_delta w, 0.9, 0.2
  end

  test "openings: only door-wide gaps" do
    segs = [{{2.0, -2.0}, {2.0, 0.0}}, {{2.0, 0.9}, {2.0, 3.0}}, {{2.0, 6.0}, {2.0, 8.0}}]
    assert [%{centre: {2.0, 0.45}}] = Lines.openings(segs, 10.0)
  end

  test "the a priori map's walls and doors near the robot join the LPS" do
    f =
      fusion(
        walls: [{{3.0, -5.0}, {3.0, 5.0}}, {{50.0, 0.0}, {51.0, 0.0}}],
        doors: [%{name: :d, centre: {3.0, 1.0}, width: 1.0, heading: 0.0}]
      )
      |> Fusion.put_world_pose({1.0, 0.0, 0.0})

    lps = Fusion.lps(f)
    assert [{{2.0, -5.0}, {2.0, 5.0}}] = lps.segments
    assert [%{name: :d, centre: {2.0, 1.0}}] = lps.doors
  end
end
