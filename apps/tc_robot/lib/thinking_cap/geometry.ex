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

  ## Frames

  A pose `{x, y, θ}` is a frame: x forward, y to the left (REP-103).
  `to_frame/2` puts a world point in a pose's frame; `relative/2` gives one
  pose in another's frame (the motion between two odometry poses);
  `compose/2` is its inverse, the pose reached by such a motion.
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

  @typedoc "A pose in the plane, {x, y, θ} (metres, radians)."
  @type pose :: {number(), number(), number()}

  @doc """
  The world point `p` in the frame of `pose` (x forward, y to the left).

      iex> ThinkingCap.Geometry.to_frame({1.0, 2.0, 0.0}, {3.0, 2.0})
      {2.0, 0.0}
  """
  @spec to_frame(pose(), point()) :: {float(), float()}
  def to_frame({x, y, theta}, {px, py}) do
    dx = px - x
    dy = py - y
    c = :math.cos(theta)
    s = :math.sin(theta)
    {c * dx + s * dy, -s * dx + c * dy}
  end

  @doc """
  The pose `to` in the frame of the pose `from`: `{dx, dy, dθ}`, `dθ` in
  (−π, π]. Between two odometry poses, the motion from one to the other.

      iex> ThinkingCap.Geometry.relative({1.0, 1.0, 0.0}, {3.0, 1.0, 1.0})
      {2.0, 0.0, 1.0}
  """
  @spec relative(pose(), pose()) :: {float(), float(), float()}
  def relative({x0, y0, th0}, {x1, y1, th1}) do
    {c, s} = {:math.cos(th0), :math.sin(th0)}
    {ex, ey} = {x1 - x0, y1 - y0}
    {c * ex + s * ey, -s * ex + c * ey, normalize_angle(th1 - th0)}
  end

  @doc """
  The pose reached from `pose` by the motion `delta` given in its frame
  (pose composition, the inverse of `relative/2`).

      iex> ThinkingCap.Geometry.compose({1.0, 1.0, 0.0}, {2.0, 0.0, 1.0})
      {3.0, 1.0, 1.0}
  """
  @spec compose(pose(), pose()) :: {float(), float(), float()}
  def compose({x, y, th}, {dx, dy, dth}) do
    {c, s} = {:math.cos(th), :math.sin(th)}
    {x + c * dx - s * dy, y + s * dx + c * dy, normalize_angle(th + dth)}
  end
end
