defmodule ThinkingCap.Geometry do
  @moduledoc """
  Plane geometry shared by every app above the runtime: angles and
  distances, in one place so that the robot, the simulator, cognition and
  the dashboard agree to the last bit.

  ## Angles

  Angles are radians. `normalize_angle/1` wraps an angle into the interval
  (−π, π]: π is kept as π, and −π (or any odd multiple of π) becomes +π, so
  that every direction has exactly one representation. An angle already in
  (−π, π] is returned unchanged (as a float), so normalising twice, or
  normalising an angle that needs no wrapping, costs no precision.
  `angle_diff/2` is the signed, shortest turn from one angle to another in
  the same interval.

  ## Distances

  `segment_distance/3` is the distance from a point to a segment (not to its
  line); a segment of zero length is a point.
  """

  @pi :math.pi()
  @two_pi 2 * :math.pi()

  @typedoc "A point in the plane, {x, y} (metres)."
  @type point :: {number(), number()}

  @doc """
  An angle wrapped into (−π, π].

      iex> ThinkingCap.Geometry.normalize_angle(:math.pi())
      3.141592653589793
      iex> ThinkingCap.Geometry.normalize_angle(-:math.pi())
      3.141592653589793
      iex> ThinkingCap.Geometry.normalize_angle(0)
      0.0
  """
  @spec normalize_angle(number()) :: float()
  def normalize_angle(a) when a > -@pi and a <= @pi, do: a * 1.0

  def normalize_angle(a) do
    a = :math.fmod(a * 1.0, @two_pi)

    cond do
      a > @pi -> a - @two_pi
      a <= -@pi -> a + @two_pi
      true -> a
    end
  end

  @doc """
  The signed, shortest turn from `from` to `to`, in (−π, π]:
  `normalize_angle(to - from)`.

      iex> ThinkingCap.Geometry.angle_diff(3.0, -3.0)
      -0.28318530717958623
  """
  @spec angle_diff(number(), number()) :: float()
  def angle_diff(to, from), do: normalize_angle(to - from)

  @doc """
  The distance from point `p` to the segment from `a` to `b`: to the
  nearest point of the segment, an end if the perpendicular foot falls
  outside it. A zero-length segment (`a == b`) is the point `a`.

      iex> ThinkingCap.Geometry.segment_distance({1.0, 1.0}, {0.0, 0.0}, {2.0, 0.0})
      1.0
      iex> ThinkingCap.Geometry.segment_distance({3.0, 4.0}, {0.0, 0.0}, {0.0, 0.0})
      5.0
  """
  @spec segment_distance(point(), point(), point()) :: float()
  def segment_distance({x, y}, {ax, ay}, {bx, by}) do
    {ex, ey} = {bx - ax, by - ay}
    len2 = ex * ex + ey * ey
    u = if len2 == 0, do: 0.0, else: max(0.0, min(1.0, ((x - ax) * ex + (y - ay) * ey) / len2))
    :math.sqrt((ax + u * ex - x) ** 2 + (ay + u * ey - y) ** 2)
  end
end
