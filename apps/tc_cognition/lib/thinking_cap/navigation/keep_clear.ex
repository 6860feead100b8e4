defmodule ThinkingCap.Navigation.KeepClear do
  @moduledoc """
  Moves a planned path away from obstacles where there is room, as a
  costmap's inflation gradient does in Nav2: a shortest path hugs the
  walls and cuts the corners as closely as the robot's radius allows, and
  a robot driving it has its obstacle avoidance on most of the way, which
  slows it down.

  Each inner point of the path climbs the distance field (the distance
  from each cell to the nearest obstacle cell) one cell at a time, until
  it is `prefer` metres from the nearest obstacle, it has moved
  `max_shift` metres, or it stops gaining (a corridor's middle, a door's
  centre line). A moved point is kept only if the path's two segments
  that meet at it keep at least the clearance that the old ones had (or
  `radius`, whichever is less): the path never comes closer to an
  obstacle than it was. The first and the last points stay where they
  are.
  """

  alias ThinkingCap.Navigation.Grid

  @typedoc """
  A distance field: for each cell of `grid` (row-major), the distance in
  cells from its centre to the nearest obstacle cell's centre, as native
  32-bit floats (`ThinkingCap.Navigation.Core.GridNif.edt/3`).
  """
  @type field :: %{grid: Grid.t(), distances: binary()}

  @type point :: {float(), float()}

  @doc """
  The path with its inner points moved away from obstacles. Options:
  `prefer` (m, the wanted distance from the nearest obstacle), `radius`
  (m, the least distance a segment must keep, e.g. the planner's
  inflation radius), `max_shift` (m, default `prefer`).
  """
  @spec push([point()], field(), keyword()) :: [point()]
  def push(path, field, opts)

  def push([_, _, _ | _] = path, %{grid: %Grid{}} = field, opts) do
    prefer = Keyword.fetch!(opts, :prefer)
    radius = Keyword.fetch!(opts, :radius)
    max_shift = Keyword.get(opts, :max_shift, prefer)
    [first | rest] = path
    {inner, [last]} = Enum.split(rest, -1)

    {moved, _} =
      inner
      |> Enum.zip(tl(rest))
      |> Enum.map_reduce(first, fn {point, next}, previous ->
        candidate = climb(field, point, prefer, max_shift)

        old =
          min(segment_clearance(field, previous, point), segment_clearance(field, point, next))

        new =
          min(
            segment_clearance(field, previous, candidate),
            segment_clearance(field, candidate, next)
          )

        kept = if candidate != point and new >= min(old, radius), do: candidate, else: point
        {kept, kept}
      end)

    [first | moved] ++ [last]
  end

  def push(path, _field, _opts), do: path

  @doc "The distance (m) from a point to the nearest obstacle cell's centre, `0.0` off the grid."
  @spec clearance(field(), point()) :: float()
  def clearance(%{grid: grid} = field, point) do
    {col, row} = Grid.cell_of(grid, point)
    at(field, col, row) * grid.resolution
  end

  # up the distance field, a cell at a time
  defp climb(%{grid: grid} = field, point, prefer, max_shift) do
    steps = max(0, floor(max_shift / grid.resolution))
    climb(field, point, clearance(field, point), prefer, steps)
  end

  defp climb(_field, point, d, prefer, steps) when d >= prefer or steps == 0, do: point

  defp climb(%{grid: grid} = field, {x, y} = point, d, prefer, steps) do
    {col, row} = Grid.cell_of(grid, point)
    gx = at(field, col + 1, row) - at(field, col - 1, row)
    gy = at(field, col, row + 1) - at(field, col, row - 1)
    norm = :math.sqrt(gx * gx + gy * gy)

    if norm == 0.0 do
      point
    else
      step = grid.resolution
      next = {x + step * gx / norm, y + step * gy / norm}
      nd = clearance(field, next)
      if nd > d, do: climb(field, next, nd, prefer, steps - 1), else: point
    end
  end

  @doc "The least clearance (m) along a segment, sampled every half cell."
  @spec segment_clearance(field(), point(), point()) :: float()
  def segment_clearance(%{grid: grid} = field, {ax, ay} = a, {bx, by}) do
    length = :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
    n = max(1, ceil(length / (grid.resolution / 2)))

    Enum.reduce(1..n, clearance(field, a), fn i, least ->
      t = i / n
      min(least, clearance(field, {ax + t * (bx - ax), ay + t * (by - ay)}))
    end)
  end

  defp at(%{grid: %Grid{width: w, height: h}, distances: d}, col, row)
       when col >= 0 and row >= 0 and col < w and row < h do
    <<v::float-32-native>> = binary_part(d, (row * w + col) * 4, 4)
    v
  end

  defp at(_field, _col, _row), do: 0.0
end
