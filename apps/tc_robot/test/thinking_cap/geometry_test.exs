defmodule ThinkingCap.GeometryTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Geometry

  doctest ThinkingCap.Geometry

  @pi :math.pi()

  describe "normalize_angle/1" do
    test "keeps an angle already in (−π, π] unchanged, as a float" do
      for a <- [0, 0.5, -0.5, 1.0e-20, -1.0e-20, @pi, -@pi + 1.0e-12, 3] do
        assert Geometry.normalize_angle(a) === a * 1.0
      end
    end

    test "π stays π and −π becomes π" do
      assert Geometry.normalize_angle(@pi) == @pi
      assert Geometry.normalize_angle(-@pi) == @pi
    end

    test "odd multiples of π wrap to ±π (to rounding: k·π is not exact)" do
      for k <- [3, -3, 5, -5, 101, -101] do
        assert_in_delta abs(Geometry.normalize_angle(k * @pi)), @pi, 1.0e-12
      end
    end

    test "multiples of 2π wrap to 0" do
      for k <- [1, -1, 2, -2, 50, -50] do
        assert_in_delta Geometry.normalize_angle(k * 2 * @pi), 0.0, 1.0e-12
      end
    end

    test "wraps positive and negative angles by whole turns" do
      assert_in_delta Geometry.normalize_angle(7.0), 7.0 - 2 * @pi, 1.0e-12
      assert_in_delta Geometry.normalize_angle(-7.0), 2 * @pi - 7.0, 1.0e-12
      assert_in_delta Geometry.normalize_angle(-3 * @pi / 2), @pi / 2, 1.0e-12
      assert_in_delta Geometry.normalize_angle(3 * @pi / 2), -@pi / 2, 1.0e-12
      assert_in_delta Geometry.normalize_angle(1000.0), 1000.0 - 159 * 2 * @pi, 1.0e-9
    end

    test "always lands in (−π, π]" do
      for i <- -2000..2000 do
        a = Geometry.normalize_angle(i * 0.0137 + i * i * 1.0e-3)
        assert a > -@pi and a <= @pi
      end
    end
  end

  describe "angle_diff/2" do
    test "is the shortest signed turn, across the ±π seam" do
      assert_in_delta Geometry.angle_diff(3.0, -3.0), 6.0 - 2 * @pi, 1.0e-12
      assert_in_delta Geometry.angle_diff(-3.0, 3.0), 2 * @pi - 6.0, 1.0e-12
      assert Geometry.angle_diff(0.25, 0.25) == 0.0
      assert Geometry.angle_diff(@pi, 0) == @pi
      assert Geometry.angle_diff(0, @pi) == @pi
    end
  end

  describe "segment_distance/3" do
    test "perpendicular foot inside the segment" do
      assert Geometry.segment_distance({1.0, 2.0}, {0.0, 0.0}, {3.0, 0.0}) == 2.0
    end

    test "beyond an end, the distance to that end" do
      assert Geometry.segment_distance({-3.0, 4.0}, {0.0, 0.0}, {1.0, 0.0}) == 5.0
      assert Geometry.segment_distance({4.0, 4.0}, {0.0, 0.0}, {1.0, 0.0}) == 5.0
    end

    test "a point on the segment is at distance 0" do
      assert Geometry.segment_distance({0.5, 0.5}, {0.0, 0.0}, {1.0, 1.0}) == 0.0
    end

    test "a zero-length segment is a point" do
      assert Geometry.segment_distance({3.0, 4.0}, {0.0, 0.0}, {0.0, 0.0}) == 5.0
      assert Geometry.segment_distance({1, 1}, {1, 1}, {1, 1}) == 0.0
    end
  end
end
