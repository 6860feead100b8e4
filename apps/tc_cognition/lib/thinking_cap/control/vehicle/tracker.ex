defmodule ThinkingCap.Control.Vehicle.Tracker do
  @moduledoc """
  Follows a path of segments driven one way each (forwards or in
  reverse, `ThinkingCap.Control.Vehicle.Planner`) with regulated pure
  pursuit (Macenski et al.): the robot steers on the circle through the
  point `lookahead` metres ahead on the path (the curvature
  `2 y / d²` of that point in the robot frame, the same in reverse),
  clamped to the drive's tightest curvature (`lookahead` shrinks at low
  speed, down to 0.35 m, so that tight curves are not cut). The speed is regulated down
  on tight curves and near the end of a segment (a cusp, where the robot
  stops and changes direction, or the goal), so that it stops there.

  The last segment is extended straight beyond its end for the
  lookahead, so the robot stays on the line into a dock instead of
  turning towards its end point.
  """

  alias ThinkingCap.Geometry
  alias ThinkingCap.Robot.Kinematics

  @typedoc "A segment ready to follow: direction, points and their arc lengths."
  @type seg :: %{direction: 1 | -1, points: tuple(), s: tuple()}

  @typedoc "`remaining`: metres left on the current segment at the last step."
  @type t :: %__MODULE__{
          segments: tuple(),
          index: non_neg_integer(),
          nearest: non_neg_integer(),
          remaining: float(),
          speed: float()
        }

  defstruct segments: {}, index: 0, nearest: 0, remaining: 0.0, speed: 0.0

  @doc "A tracker at the start of `segments` (`%{direction:, poses: [{x, y, θ}] | points: [{x, y}]}`)."
  @spec new([map()]) :: t()
  def new(segments) do
    segs =
      segments
      |> Enum.map(fn seg ->
        points = Map.get(seg, :points) || Enum.map(seg.poses, fn {x, y, _} -> {x, y} end)
        %{direction: seg.direction, points: List.to_tuple(points), s: arc_lengths(points)}
      end)
      |> Enum.reject(&(tuple_size(&1.points) < 2))

    %__MODULE__{segments: List.to_tuple(segs)}
  end

  @doc "All the path's points, for display."
  @spec points(t()) :: [{float(), float()}]
  def points(%__MODULE__{segments: segs}),
    do: segs |> Tuple.to_list() |> Enum.flat_map(&Tuple.to_list(&1.points))

  @doc "How far (m) the point `{x, y}` is from the current segment, near where the robot is."
  @spec deviation(t(), {float(), float()}) :: float()
  def deviation(%__MODULE__{} = t, {x, y}) do
    case current(t) do
      nil ->
        0.0

      seg ->
        {px, py} = elem(seg.points, nearest(seg, t.nearest, {x, y}))
        :math.sqrt((px - x) ** 2 + (py - y) ** 2)
    end
  end

  @doc """
  One control step from `pose`: `{:drive, {v, omega}, tracker}` or
  `{:done, tracker}` at the end of the path. Options: `max_curvature:`
  (1/m or `:infinity`), `max_speed:`, `max_turn_rate:`, `accel:` (m/s²,
  for slowing to a stop), `lookahead:` (m), `final_speed:` (m/s on the
  last segment).
  """
  @spec step(t(), Kinematics.pose(), keyword()) ::
          {:drive, {float(), float()}, t()} | {:done, t()}
  def step(%__MODULE__{} = t, {x, y, _} = pose, opts) do
    case current(t) do
      nil ->
        {:done, t}

      seg ->
        i = nearest(seg, t.nearest, {x, y})
        n = tuple_size(seg.points)
        t = %{t | nearest: i, remaining: elem(seg.s, n - 1) - elem(seg.s, i)}
        last? = t.index == tuple_size(t.segments) - 1

        if at_end?(seg, i, {x, y}, if(last?, do: 0.0, else: 0.1)) do
          if last?, do: {:done, t}, else: step(%{t | index: t.index + 1, nearest: 0}, pose, opts)
        else
          {v, _} = twist = command(seg, i, pose, last?, t.speed, opts)
          {:drive, twist, %{t | speed: abs(v)}}
        end
    end
  end

  defp current(%__MODULE__{segments: segs, index: i}) when i < tuple_size(segs), do: elem(segs, i)
  defp current(_t), do: nil

  # the robot's position is at or past the segment's end (along its tangent)
  defp at_end?(seg, i, {x, y}, margin) do
    n = tuple_size(seg.points)
    {ex, ey} = elem(seg.points, n - 1)
    {tx, ty} = tangent(seg)
    remaining = elem(seg.s, n - 1) - elem(seg.s, i)
    # (only near the end: a segment may curl back past its end's line)
    ((x - ex) * tx + (y - ey) * ty >= -margin and remaining < 0.6) or
      (remaining <= margin and margin > 0)
  end

  # the direction of the last piece of the segment, unit length
  defp tangent(seg) do
    n = tuple_size(seg.points)
    {ax, ay} = elem(seg.points, max(0, n - 3))
    {bx, by} = elem(seg.points, n - 1)
    l = max(:math.sqrt((bx - ax) ** 2 + (by - ay) ** 2), 1.0e-9)
    {(bx - ax) / l, (by - ay) / l}
  end

  defp command(seg, i, {x, y, th}, last?, speed, opts) do
    k_max = Keyword.fetch!(opts, :max_curvature)
    # shorter at low speed: the robot cuts tight curves less
    lookahead = min(Keyword.get(opts, :lookahead, 0.8), 0.35 + 0.9 * speed)

    vmax =
      if last?, do: Keyword.fetch!(opts, :final_speed), else: Keyword.fetch!(opts, :max_speed)

    accel = Keyword.get(opts, :accel, 0.3)
    wmax = Keyword.get(opts, :max_turn_rate, 1.0)

    {lx, ly} = lookahead_point(seg, i, lookahead, last?)
    {rx, ry} = Geometry.to_frame({x, y, th}, {lx, ly})
    d2 = max(rx * rx + ry * ry, 1.0e-6)
    kappa = clamp_curvature(2 * ry / d2, k_max)

    n = tuple_size(seg.points)
    remaining = elem(seg.s, n - 1) - elem(seg.s, i)
    # the lookahead point on the wrong side: turning hard, go slow
    wrong_way = rx * seg.direction < 0

    v =
      vmax
      |> min(regulated(vmax, kappa, k_max))
      |> min(max(0.06, :math.sqrt(2 * accel * max(remaining, 0.0))))
      |> min(if(abs(kappa) > 1.0e-6, do: 0.9 * wmax / abs(kappa), else: vmax))
      |> then(&if(wrong_way, do: min(&1, 0.2), else: &1))

    v = v * seg.direction
    {v, v * kappa}
  end

  defp regulated(vmax, _kappa, :infinity), do: vmax
  defp regulated(vmax, kappa, k_max), do: vmax * max(0.35, 1 - 0.6 * abs(kappa) / k_max)

  defp clamp_curvature(k, :infinity), do: k
  defp clamp_curvature(k, k_max), do: k |> max(-k_max) |> min(k_max)

  # the path point `lookahead` metres on from point i; beyond the end of
  # the last segment, the straight extension of its end
  defp lookahead_point(seg, i, lookahead, last?) do
    n = tuple_size(seg.points)
    target = elem(seg.s, i) + lookahead
    total = elem(seg.s, n - 1)

    if target >= total do
      {ex, ey} = elem(seg.points, n - 1)

      if last? do
        {tx, ty} = tangent(seg)
        beyond = target - total
        {ex + tx * beyond, ey + ty * beyond}
      else
        {ex, ey}
      end
    else
      j = Enum.find(i..(n - 1), n - 1, &(elem(seg.s, &1) >= target))
      elem(seg.points, j)
    end
  end

  # the index of the point nearest {x, y}, searched from `from` on over
  # the next 60 points (about 3 m)
  defp nearest(seg, from, {x, y}) do
    n = tuple_size(seg.points)
    last = min(n - 1, from + 60)

    Enum.min_by(from..last, fn j ->
      {px, py} = elem(seg.points, j)
      (px - x) ** 2 + (py - y) ** 2
    end)
  end

  defp arc_lengths(points) do
    {lengths, _} =
      Enum.map_reduce(points, {nil, 0.0}, fn
        p, {nil, _} ->
          {0.0, {p, 0.0}}

        {x, y} = p, {{px, py}, s} ->
          s = s + :math.sqrt((x - px) ** 2 + (y - py) ** 2)
          {s, {p, s}}
      end)

    List.to_tuple(lengths)
  end
end
