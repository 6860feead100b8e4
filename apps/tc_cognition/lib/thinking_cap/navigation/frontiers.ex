defmodule ThinkingCap.Navigation.Frontiers do
  @moduledoc """
  Frontiers for exploration (Yamauchi's frontier-based exploration, as
  explore_lite uses it): the boundaries between known free space and
  unknown space of an occupancy grid. A frontier cell is a free cell
  (occupancy below `free_below`, default 20) with an unknown 4-neighbour;
  frontier cells are grouped 8-connected, and groups smaller than
  `min_length` metres (default 0.4: a gap the robot could not see
  through) are dropped.

  `choose/3` picks the one to visit: the cheapest by explore_lite's rule,
  `distance − gain · length` (default gain 1), among those not within
  `blacklist_radius` of a point given up, with the distance along the
  path when the caller gives the paths' lengths: a frontier behind a
  wall is then as far as the way round it.
  """

  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}
  alias ThinkingCap.Navigation.Core.GridNif

  @type frontier :: %{cells: pos_integer(), length: float(), point: {float(), float()}}

  @doc """
  The frontiers of a map: each with its number of cells, its `length` (m)
  and the `point` of its cell nearest its centroid (world).
  """
  @spec find(OccupancyGrid.t(), keyword()) :: [frontier()]
  def find(%OccupancyGrid{} = map, opts \\ []) do
    res = map.resolution
    min_cells = max(1, round(Keyword.get(opts, :min_length, 0.4) / res))
    free_below = Keyword.get(opts, :free_below, 20)

    grid = %Grid{
      width: map.width,
      height: map.height,
      cells: "",
      resolution: res,
      origin: map.origin
    }

    for {n, cell} <- GridNif.frontiers(map.data, map.width, map.height, free_below, min_cells) do
      %{cells: n, length: n * res, point: Grid.centre(grid, cell)}
    end
    |> Enum.sort_by(&{-&1.cells, &1.point})
  end

  @doc """
  The frontier to visit from `from`: the least `distance − gain · length`
  (option `gain`, default 1), skipping those within `blacklist_radius`
  (default 0.75 m) of a point in `blacklist`; nil if none is left. The
  distance is the straight line's, or with option `distances` (a map from
  a frontier's point to the length of the path there, `nil` or missing
  for no path) the path's, and a frontier without a path is skipped.
  """
  @spec choose([frontier()], {number(), number()}, keyword()) :: frontier() | nil
  def choose(frontiers, {x, y}, opts \\ []) do
    gain = Keyword.get(opts, :gain, 1.0)
    radius = Keyword.get(opts, :blacklist_radius, 0.75)
    blacklist = Keyword.get(opts, :blacklist, [])

    distances = Keyword.get(opts, :distances)

    frontiers
    |> Enum.reject(fn %{point: p} -> Enum.any?(blacklist, &(dist(&1, p) < radius)) end)
    |> Enum.map(fn %{point: p} = f ->
      {f, if(distances, do: Map.get(distances, p), else: dist(p, {x, y}))}
    end)
    |> Enum.reject(fn {_, d} -> d == nil end)
    |> Enum.min_by(fn {%{length: l}, d} -> d - gain * l end, fn -> {nil, nil} end)
    |> elem(0)
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
