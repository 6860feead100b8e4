defmodule ThinkingCap.Control.GeometryTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.Geometry
  alias ThinkingCap.Perception.LPS

  @pi :math.pi()

  defp close({ax, ay}, {bx, by}), do: abs(ax - bx) < 1.0e-9 and abs(ay - by) < 1.0e-9

  test "world points in the robot frame; distance and bearing" do
    # facing +y from (1, 2): a point at (1, 3) is 1 m ahead, (0, 2) 1 m to the left
    assert close(Geometry.to_robot({1.0, 2.0, @pi / 2}, {1.0, 3.0}), {1.0, 0.0})
    assert close(Geometry.to_robot({1.0, 2.0, @pi / 2}, {0.0, 2.0}), {0.0, 1.0})
    assert {d, b} = Geometry.polar({-1.0, -1.0})
    assert_in_delta d, :math.sqrt(2), 1.0e-12
    assert_in_delta b, -3 * @pi / 4, 1.0e-12
  end

  test "ahead: free distance in the swept corridor, from the robot's edge" do
    lps = LPS.from_points([{1.0, 0.0}, {0.6, 0.5}, {-0.4, 0.0}])
    # (0.6, 0.5) is outside a 0.2 + 0.1 corridor; (-0.4, 0) is behind
    assert_in_delta Geometry.ahead(lps, 0.2, 0.1), 1.0 * :math.cos(2.5 * @pi / 180) - 0.2, 1.0e-9
    assert Geometry.ahead(LPS.empty(range: 4.0), 0.2) == 3.8
    assert Geometry.ahead(LPS.from_points([{0.1, 0.0}]), 0.2) == 0.0
  end

  test "clearance: nearest in a sector minus the radius, never negative" do
    lps = LPS.from_points([{0.0, 0.5}, {0.0, -0.1}])
    assert_in_delta Geometry.clearance(lps, 1.0, 2.0, 0.2), 0.3, 1.0e-12
    assert Geometry.clearance(lps, -2.0, -1.0, 0.2) == 0.0
  end

  test "lookahead: pure pursuit along a polyline" do
    path = [{0.0, 0.0}, {1.0, 0.0}, {1.0, 2.0}]
    {point, remaining} = Geometry.lookahead(path, {0.8, 0.1}, 0.6)
    assert close(point, {1.0, 0.4})
    assert_in_delta remaining, 2.2, 1.0e-12

    # beyond the end: the end
    {point, remaining} = Geometry.lookahead(path, {1.1, 1.9}, 0.6)
    assert close(point, {1.0, 2.0})
    assert_in_delta remaining, 0.1, 1.0e-12

    # before the start: from the start
    {point, _} = Geometry.lookahead(path, {-1.0, 0.0}, 0.5)
    assert close(point, {0.5, 0.0})

    assert Geometry.lookahead([{2, 3}], {0.0, 0.0}, 0.5) == {{2.0, 3.0}, 0.0}
  end

  test "wall: from segments when given, else from the nearest point beside" do
    # a left wall 0.5 m away, turning towards the robot ahead by 0.2 rad
    seg = {{-1.0, 0.5 + :math.tan(0.2)}, {1.0, 0.5 - :math.tan(0.2)}}
    lps = %{LPS.empty() | segments: [seg]}
    assert {d, approach} = Geometry.wall(lps, :left)
    assert_in_delta d, 0.5 * :math.cos(0.2), 1.0e-9
    assert_in_delta approach, 0.2, 1.0e-9
    assert Geometry.wall(lps, :right) == nil

    # a right wall, drawn back to front, falling away ahead
    lps = %{
      LPS.empty()
      | segments: [{{1.0, -0.5 - :math.tan(0.2)}, {-1.0, -0.5 + :math.tan(0.2)}}]
    }

    assert {_, approach} = Geometry.wall(lps, :right)
    assert_in_delta approach, -0.2, 1.0e-9

    # points of a parallel wall: nearest abeam, approach within a sector
    lps = LPS.from_points(for i <- 0..40, do: {-1.0 + i * 0.05, -0.6})
    assert {d, approach} = Geometry.wall(lps, :right)
    assert_in_delta d, 0.6, 0.01
    assert abs(approach) < 0.05
    assert Geometry.wall(lps, :left) == nil
  end
end
