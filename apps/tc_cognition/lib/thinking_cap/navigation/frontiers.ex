defmodule ThinkingCap.Navigation.Frontiers do
  @moduledoc """
  Frontiers for exploration (Yamauchi's frontier-based exploration, as
  explore_lite uses it): the boundaries between known free space and
  unknown space of an occupancy grid. A frontier cell is a free cell
  (occupancy below `free_below`, default 20) with an unknown 4-neighbour;
  frontier cells are grouped 8-connected, and groups smaller than
  `min_length` metres (default 0.4: a gap the robot could not see
  through) are dropped. Each frontier carries the unknown `area` it opens
  onto (`unknown_area/3`); one opening onto less than `min_area` (m²,
  default 0: none dropped) is dropped too: a pocket of unknown cells the
  laser has seen past on every side, not worth a trip.

  `choose/3` picks the one to visit: the cheapest by explore_lite's rule,
  `distance − gain · length − area_gain · area` (defaults 1 and 0), among
  those not within `blacklist_radius` of a point given up, with the
  distance along the path when the caller gives the paths' lengths: a
  frontier behind a wall is then as far as the way round it.
  """

  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}
  alias ThinkingCap.Navigation.Core.GridNif

  @type frontier :: %{
          cells: pos_integer(),
          length: float(),
          point: {float(), float()},
          area: float()
        }

  @doc """
  The frontiers of a map: each with its number of cells, its `length` (m),
  the `point` of its cell nearest its centroid (world) and the unknown
  `area` (m²) it opens onto (`unknown_area/3`, options `area_radius` and
  `area_cap`). Those under `min_length` m or `min_area` m² are left out.
  The areas are counted only when asked for (`area: true`) or when
  `min_area` is above 0; else each `area` is 0.0.
  """
  @spec find(OccupancyGrid.t(), keyword()) :: [frontier()]
  def find(%OccupancyGrid{} = map, opts \\ []) do
    res = map.resolution
    min_cells = max(1, round(Keyword.get(opts, :min_length, 0.4) / res))
    free_below = Keyword.get(opts, :free_below, 20)
    min_area = Keyword.get(opts, :min_area, 0.0)
    area? = Keyword.get(opts, :area, false) or min_area > 0

    grid = %Grid{
      width: map.width,
      height: map.height,
      cells: "",
      resolution: res,
      origin: map.origin
    }

    for {n, cell} <- GridNif.frontiers(map.data, map.width, map.height, free_below, min_cells) do
      point = Grid.centre(grid, cell)
      area = if area?, do: unknown_area(map, point, opts), else: 0.0
      %{cells: n, length: n * res, point: point, area: area}
    end
    |> Enum.reject(&(&1.area < min_area))
    |> Enum.sort_by(&{-&1.cells, &1.point})
  end

  @doc """
  The unknown area (m²) a frontier opens onto: the unknown cells reached
  from its `point` through unknown space, never past an occupied cell
  (occupancy 50 or more), within `area_radius` m of it (default 3), counted
  on a 0.1 m lattice up to `area_cap` m² (default 6). A door into an unseen
  room reaches the cap; a pocket behind a chair's leg, or a sliver
  between a wall and its second, bent drawing, a few hundredths.
  """
  @spec unknown_area(OccupancyGrid.t(), {number(), number()}, keyword()) :: float()
  def unknown_area(%OccupancyGrid{resolution: res} = map, point, opts \\ []) do
    step = max(1, round(0.1 / res))
    k = Keyword.get(opts, :area_radius, 3.0) / res
    cell_area = (step * res) ** 2
    cap = ceil(Keyword.get(opts, :area_cap, 6.0) / cell_area)
    {c0, r0} = OccupancyGrid.cell_of(map, point)
    near? = fn {c, r} -> (c - c0) ** 2 + (r - r0) ** 2 <= k * k end

    # one seed, the point's cell or its nearest unknown neighbour: seeds
    # on different lattices would count the same space twice
    [{0, 0}, {1, 0}, {-1, 0}, {0, 1}, {0, -1}, {1, 1}, {-1, 1}, {1, -1}, {-1, -1}]
    |> Enum.map(fn {dc, dr} -> {c0 + dc, r0 + dr} end)
    |> Enum.find(&unknown?(map, &1))
    |> case do
      nil -> 0.0
      seed -> flood(map, [seed], [], MapSet.new([seed]), step, near?, cap) * cell_area
    end
  end

  # breadth-first over unknown cells, `step` cells at a time (the cells
  # stepped over not occupied), until none is left or `cap` are counted
  defp flood(_map, [], [], seen, _step, _near?, cap), do: min(MapSet.size(seen), cap)

  defp flood(map, [], next, seen, step, near?, cap),
    do: flood(map, next, [], seen, step, near?, cap)

  defp flood(map, [{c, r} | rest], next, seen, step, near?, cap) do
    if MapSet.size(seen) >= cap do
      cap
    else
      {next, seen} =
        Enum.reduce([{1, 0}, {-1, 0}, {0, 1}, {0, -1}], {next, seen}, fn {dc, dr}, {nx, sn} ->
          cell = {c + step * dc, r + step * dr}

          if near?.(cell) and not MapSet.member?(sn, cell) and unknown?(map, cell) and
               passable?(map, {c, r}, {dc, dr}, step),
             do: {[cell | nx], MapSet.put(sn, cell)},
             else: {nx, sn}
        end)

      flood(map, rest, next, seen, step, near?, cap)
    end
  end

  defp unknown?(map, cell), do: OccupancyGrid.value(map, cell) == -1

  # the cells between a lattice cell and its neighbour are not occupied
  defp passable?(map, {c, r}, {dc, dr}, step),
    do: Enum.all?(1..(step - 1)//1, &(OccupancyGrid.value(map, {c + &1 * dc, r + &1 * dr}) < 50))

  @doc """
  The frontier to visit from `from`: the least `cost/3`, skipping those
  within `blacklist_radius`
  (default 0.75 m) of a point in `blacklist`; nil if none is left. The
  distance is the straight line's, or with option `distances` (a map from
  a frontier's point to the length of the path there, `nil` or missing
  for no path) the path's, and a frontier without a path is skipped.
  """
  @spec choose([frontier()], {number(), number()}, keyword()) :: frontier() | nil
  def choose(frontiers, {x, y}, opts \\ []) do
    radius = Keyword.get(opts, :blacklist_radius, 0.75)
    blacklist = Keyword.get(opts, :blacklist, [])

    distances = Keyword.get(opts, :distances)

    frontiers
    |> Enum.reject(fn %{point: p} -> Enum.any?(blacklist, &(dist(&1, p) < radius)) end)
    |> Enum.map(fn %{point: p} = f ->
      {f, if(distances, do: Map.get(distances, p), else: dist(p, {x, y}))}
    end)
    |> Enum.reject(fn {_, d} -> d == nil end)
    |> Enum.min_by(fn {f, d} -> cost(f, d, opts) end, fn -> {nil, nil} end)
    |> elem(0)
  end

  @doc """
  What visiting a frontier `distance` m away costs: `distance − gain ·
  length − area_gain · area` (options `gain`, default 1, and `area_gain`,
  m of way a square metre of unknown area is worth, default 0).
  """
  @spec cost(frontier(), number(), keyword()) :: float()
  def cost(frontier, distance, opts \\ []) do
    gain = Keyword.get(opts, :gain, 1.0)
    area_gain = Keyword.get(opts, :area_gain, 0.0)
    distance - gain * frontier.length - area_gain * Map.get(frontier, :area, 0.0)
  end

  @doc "Whether any unknown cell lies within `radius` metres of a point (the frontier is still there)."
  @spec unknown_near?(OccupancyGrid.t(), {number(), number()}, float()) :: boolean()
  def unknown_near?(%OccupancyGrid{} = map, point, radius) do
    {c, r} = OccupancyGrid.cell_of(map, point)
    k = ceil(radius / map.resolution)

    disc = for dc <- -k..k, dr <- -k..k, dc * dc + dr * dr <= k * k, do: {c + dc, r + dr}
    Enum.any?(disc, fn cell -> inside?(map, cell) and OccupancyGrid.value(map, cell) == -1 end)
  end

  @doc """
  Whether a frontier is still there: at least `min_length` metres of
  frontier cells (free, below `free_below`, with an unknown 4-neighbour
  inside the map; defaults as in `find/2`) within `radius` metres of a
  point. Unknown space behind a wall near the point does not count: it
  borders no free cell.
  """
  @spec remains?(OccupancyGrid.t(), {number(), number()}, float(), keyword()) :: boolean()
  def remains?(%OccupancyGrid{} = map, point, radius, opts \\ []) do
    {c, r} = OccupancyGrid.cell_of(map, point)
    k = ceil(radius / map.resolution)
    need = max(1, round(Keyword.get(opts, :min_length, 0.4) / map.resolution))
    free_below = Keyword.get(opts, :free_below, 20)

    disc = for dc <- -k..k, dr <- -k..k, dc * dc + dr * dr <= k * k, do: {c + dc, r + dr}

    disc
    |> Stream.filter(&frontier_cell?(map, &1, free_below))
    |> Enum.take(need)
    |> length() == need
  end

  defp frontier_cell?(map, {c, r} = cell, free_below) do
    v = OccupancyGrid.value(map, cell)

    inside?(map, cell) and v >= 0 and v < free_below and
      Enum.any?([{c + 1, r}, {c - 1, r}, {c, r + 1}, {c, r - 1}], fn n ->
        inside?(map, n) and OccupancyGrid.value(map, n) == -1
      end)
  end

  defp inside?(%{width: w, height: h}, {c, r}), do: c >= 0 and r >= 0 and c < w and r < h

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((ax - bx) ** 2 + (ay - by) ** 2)
end
