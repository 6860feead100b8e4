defmodule ThinkingCap.Navigation.Maps.Ray do
  @moduledoc false
  # Grid traversal of a ray (Amanatides & Woo's DDA) and the beams of a
  # laser scan, shared by the occupancy maps.

  @doc false
  # the cells `{col, row}` the segment from `p0` to `p1` (world, m) passes
  # through, in order, from the cell of `p0` to the cell of `p1`
  @spec cells({float(), float()}, float(), {number(), number()}, {number(), number()}) ::
          [{integer(), integer()}]
  def cells({ox, oy}, res, {x0, y0}, {x1, y1}) do
    {u0, v0} = {(x0 - ox) / res, (y0 - oy) / res}
    {u1, v1} = {(x1 - ox) / res, (y1 - oy) / res}
    {c, r} = {floor(u0), floor(v0)}
    {c_end, r_end} = {floor(u1), floor(v1)}
    {du, dv} = {u1 - u0, v1 - v0}
    {step_c, t_max_c, t_delta_c} = axis(u0, du, c)
    {step_r, t_max_r, t_delta_r} = axis(v0, dv, r)
    n = abs(c_end - c) + abs(r_end - r)
    walk({c, r}, n, step_c, step_r, t_max_c, t_max_r, t_delta_c, t_delta_r, [])
  end

  defp axis(_p, d, _cell) when d == 0, do: {0, :infinity, :infinity}
  defp axis(p, d, cell) when d > 0, do: {1, (cell + 1 - p) / d, 1 / d}
  defp axis(p, d, cell), do: {-1, (p - cell) / -d, -1 / d}

  defp walk(cell, 0, _sc, _sr, _tc, _tr, _dc, _dr, acc), do: Enum.reverse([cell | acc])

  defp walk({c, r} = cell, n, sc, sr, tc, tr, dc, dr, acc) do
    if tc < tr,
      do: walk({c + sc, r}, n - 1, sc, sr, tc + dc, tr, dc, dr, [cell | acc]),
      else: walk({c, r + sr}, n - 1, sc, sr, tc, tr + dr, dc, dr, [cell | acc])
  end

  @doc false
  # the beams of a scan from a sensor at `{x, y, θ}` in the world:
  # `{end_point, hit?}` for every usable reading; a reading at or beyond
  # `range_max` (no echo) gives free space up to `range_max` and no hit
  @spec beams(map(), {number(), number(), number()}) :: [{{float(), float()}, boolean()}]
  def beams(scan, {x, y, th}) do
    range_max = scan.range_max
    range_min = Map.get(scan, :range_min, 0.0)

    scan.ranges
    |> Enum.with_index()
    |> Enum.flat_map(fn {range, i} ->
      if is_number(range) and range >= range_min do
        a = th + scan.angle_min + i * scan.angle_increment
        hit? = range < range_max
        d = min(range, range_max)
        [{{x + d * :math.cos(a), y + d * :math.sin(a)}, hit?}]
      else
        []
      end
    end)
  end
end
