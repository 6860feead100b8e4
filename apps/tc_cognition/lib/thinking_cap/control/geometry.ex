defmodule ThinkingCap.Control.Geometry do
  @moduledoc """
  The crisp quantities behaviours compute before fuzzifying them: frames
  (world to robot), distances from the Local Perceptual Space, lookahead
  points on a path, walls beside the robot. Robot frame: x forward, y left,
  angles counter-clockwise (REP-103); metres and radians.
  """

  alias ThinkingCap.Perception.LPS
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @half_pi :math.pi() / 2

  @doc "A world point in the robot frame of `pose`."
  @spec to_robot({number(), number(), number()}, {number(), number()}) :: {float(), float()}
  defdelegate to_robot(pose, point), to: ThinkingCap.Geometry, as: :to_frame

  @doc "Distance and bearing (in (−π, π]) of a robot-frame point."
  @spec polar({number(), number()}) :: {float(), float()}
  def polar({x, y}), do: {:math.sqrt(x * x + y * y), normalize_angle(:math.atan2(y, x))}

  @doc """
  The robot-frame obstacle points of the LPS: one per sector that sees
  something nearer than the LPS's range, at the sector's centre angle:
  `{distance, angle}`.
  """
  @spec obstacles(LPS.t()) :: [{float(), float()}]
  def obstacles(%LPS{n: n, bins: bins, range: range} = lps) do
    for i <- 0..(n - 1), d = elem(bins, i), d < range, do: {d, LPS.sector_angle(lps, i)}
  end

  @doc """
  The free distance between the robot's edge and the nearest obstacle
  between robot-frame angles `from` and `to` (counter-clockwise, as
  `ThinkingCap.Perception.LPS.min_distance/3`), at least 0.
  """
  @spec clearance(LPS.t(), number(), number(), number()) :: float()
  def clearance(lps, from, to, radius), do: max(0.0, LPS.min_distance(lps, from, to) - radius)

  @doc """
  How far the robot can drive straight ahead before its edge reaches an
  obstacle: the nearest obstacle in front (x > 0) whose lateral offset is
  within `radius + margin`, measured along x from the robot's edge (at
  least 0; the LPS's range minus the radius when the corridor is free).
  """
  @spec ahead(LPS.t(), number(), number()) :: float()
  def ahead(%LPS{range: range} = lps, radius, margin \\ 0.1) do
    half = radius + margin

    lps
    |> obstacles()
    |> Enum.reduce(range - radius, fn {d, a}, acc ->
      x = d * :math.cos(a)
      y = d * :math.sin(a)
      if x > 0 and abs(y) <= half, do: min(acc, x - radius), else: acc
    end)
    |> max(0.0)
  end

  @doc """
  Pure pursuit on a polyline: from the point of the path nearest to
  `position`, walk `lookahead` metres further along the path; returns that
  point (the path's end if the path is shorter) and the length of path left
  from the nearest point to the end. A one-point path is its own end.
  """
  @spec lookahead([{number(), number()}], {number(), number()}, number()) ::
          {{float(), float()}, float()}
  def lookahead([only], _position, _lookahead), do: {float_point(only), 0.0}

  def lookahead([_, _ | _] = path, position, lookahead) do
    segments = Enum.zip(path, tl(path))

    # the nearest point: segment index and the distance along that segment
    {_, best_index, best_t} =
      segments
      |> Enum.with_index()
      |> Enum.reduce({:infinity, 0, 0.0}, fn {{a, b}, i}, {best, _, _} = acc ->
        {t, d} = project(a, b, position)
        if best == :infinity or d < best, do: {d, i, t}, else: acc
      end)

    rest = Enum.drop(segments, best_index)
    lengths = Enum.map(rest, fn {a, b} -> dist(a, b) end)
    remaining = Enum.sum(lengths) - best_t
    {walk(rest, best_t + lookahead), remaining}
  end

  defp walk([{a, b}], s), do: along(a, b, min(s, dist(a, b)))

  defp walk([{a, b} | rest], s) do
    len = dist(a, b)
    if s <= len, do: along(a, b, s), else: walk(rest, s - len)
  end

  # distance along a->b of the point nearest p, and the distance to it
  defp project({ax, ay} = a, {bx, by} = b, {px, py}) do
    len = dist(a, b)

    if len == 0.0 do
      {0.0, dist(a, {px, py})}
    else
      t = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / len
      t = t |> max(0.0) |> min(len)
      {t, dist(along(a, b, t), {px, py})}
    end
  end

  defp along({ax, ay} = a, {bx, by} = b, s) do
    len = dist(a, b)
    if len == 0.0, do: float_point(a), else: {ax + (bx - ax) * s / len, ay + (by - ay) * s / len}
  end

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) * (bx - ax) + (by - ay) * (by - ay))

  defp float_point({x, y}), do: {x * 1.0, y * 1.0}

  @doc """
  The wall on one side of the robot (`:left` or `:right`): `{distance,
  approach}` with the distance from the robot's centre to the wall and the
  approach angle, positive when the robot heads towards the wall (0 when
  parallel), or `nil` when nothing is seen on that side.

  Uses the LPS's segments when one lies on that side (its line's distance
  and direction), otherwise the nearest obstacle point between 35° and 145°
  on that side (nearer the front or back it is a wall ahead or behind, not
  beside) (a parallel wall's nearest point is abeam, at ±90°; a wall
  approached at angle φ has it at ±(90° − φ)).
  """
  @spec wall(LPS.t(), :left | :right) :: {float(), float()} | nil
  def wall(%LPS{} = lps, side) do
    wall_from_segments(lps.segments, side) || wall_from_bins(lps, side)
  end

  defp wall_from_segments(segments, side) do
    sign = if side == :left, do: 1, else: -1

    segments
    |> Enum.map(fn {a, b} ->
      {t, d} = project(a, b, {0.0, 0.0})
      {_, ny} = along(a, b, t)
      {d, ny, a, b}
    end)
    |> Enum.filter(fn {_d, ny, _a, _b} -> ny * sign > 0 end)
    |> Enum.min_by(fn {d, _, _, _} -> d end, fn -> nil end)
    |> case do
      nil ->
        nil

      {d, _ny, {ax, ay}, {bx, by}} ->
        # direction of the wall, folded to (-π/2, π/2]: the way the robot faces along it
        dir = :math.atan2(by - ay, bx - ax)

        dir =
          if abs(normalize_angle(dir)) > @half_pi,
            do: normalize_angle(dir + :math.pi()),
            else: dir

        # a left wall turning left ahead (dir > 0) moves away from the robot
        {d, -sign * normalize_angle(dir)}
    end
  end

  defp wall_from_bins(lps, side) do
    {from, to} = if side == :left, do: {0.61, 2.53}, else: {-2.53, -0.61}

    lps
    |> obstacles()
    |> Enum.filter(fn {_d, a} -> a >= from and a <= to end)
    |> Enum.min_by(fn {d, _a} -> d end, fn -> nil end)
    |> case do
      nil -> nil
      {d, a} when side == :left -> {d, @half_pi - a}
      {d, a} -> {d, a + @half_pi}
    end
  end
end
