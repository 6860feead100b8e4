defmodule ThinkingCap.Navigation.Maps do
  @moduledoc """
  Planning grids (`ThinkingCap.Navigation.Grid`) from a world description,
  their inflation by the robot's radius, and the cells of doors.

  The other maps of the navigation layer live beside this module:
  `ThinkingCap.Navigation.Maps.LogOdds` and
  `ThinkingCap.Navigation.Maps.FuzzyGrid` (occupancy grids built from range
  scans), `ThinkingCap.Navigation.Maps.Segments` (segment maps, line
  extraction) and `ThinkingCap.Navigation.Topology` (the topological map of
  rooms, corridors and doors).

  ## Rasterization rules

  Cells are blocked (1) or passable (0). A grid built by `grid_from_wdf/2`
  blocks:

    * every cell a **wall** segment touches, its boundary included: a wall
      lying exactly on a line between two rows of cells blocks both rows
      (walls are thin; the grid errs on the side of caution);
    * every cell of an **obstacle** polygon (cells whose centre is inside,
      and every cell its edges touch);
    * the cells of every **closed door**, the segment between its jambs
      drawn like a wall. The cells of an **open door** (`door_cells/2`) are
      cleared of the walls that merely touch them at the jambs, so the
      opening is exactly as wide as the door, and a grid built with a door
      open is the grid built with it closed with its `door_cells/2` made
      passable (unless an obstacle or the occupancy map fills the doorway);
    * the cells of the WDF's **occupancy map** (`ThinkingCap.Config.RosMap`)
      that are occupied (≥ 50 of 100) and, by default, those that are
      **unknown** (−1): a planner must not send a robot where nobody has
      looked (`unknown: :free` lets it).
  """

  alias ThinkingCap.Config.{RosMap, WDF}
  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}
  alias ThinkingCap.Navigation.Core.GridNif
  alias ThinkingCap.Navigation.Maps.Raster

  @eps 1.0e-9

  @type door :: %{
          required(:from) => {number(), number()},
          required(:to) => {number(), number()},
          optional(atom()) => term()
        }

  @doc """
  Rasterizes a world into a planning grid. Options:

    * `resolution` - cell size, m (default 0.05, or the occupancy map's;
      with an occupancy map a different resolution is refused: resampling
      is not supported);
    * `margin` - free space around the world's features, m (default 0.5,
      or 0 with an occupancy map: the map brings its own);
    * `bounds` - `{{x_min, y_min}, {x_max, y_max}}` to cover instead of the
      world's features plus margin (still aligned to the occupancy map's
      cells);
    * `closed` - the names of the doors that are closed, replacing the
      WDF's `open:` flags (doors not named are open);
    * `unknown` - `:blocked` (default) or `:free`: the occupancy map's
      unknown cells;
    * `occupied_threshold` - occupancy (0..100) from which a map cell is
      blocked (default 50).

  The grid covers the world's walls, obstacles, rooms, corridors, doors,
  beacons, areas and waypoints plus the margin, and the whole occupancy
  map. Its cells are aligned with the occupancy map's when there is one
  (then the default resolution and origin are the map's). An occupancy map
  whose origin has a non-zero yaw is refused with an `ArgumentError`: the
  grid is axis-aligned.
  """
  @spec grid_from_wdf(WDF.t(), keyword()) :: Grid.t()
  def grid_from_wdf(%WDF{} = wdf, opts \\ []) do
    map = wdf.grid
    check_map!(map, opts)
    res = if(map, do: map.resolution, else: Keyword.get(opts, :resolution, 0.05)) * 1.0
    {{ox, oy}, w, h} = frame(wdf, map, res, opts)
    geometry = {ox, oy, res, w, h}
    closed = closed_doors(wdf, opts)
    {closed_doors, open_doors} = Enum.split_with(wdf.doors, &MapSet.member?(closed, &1.name))

    walls = Enum.reduce(wdf.walls, %{}, &Raster.union(&2, segment_spans(geometry, &1)))

    openings = Enum.reduce(open_doors, %{}, &Raster.union(&2, door_spans(geometry, &1)))

    obstacles =
      Enum.reduce(wdf.obstacles, %{}, fn %{polygon: polygon}, acc ->
        Raster.union(acc, Raster.polygon(Enum.map(polygon, &Raster.to_cells(geometry, &1))))
      end)

    shut =
      Enum.reduce(closed_doors, %{}, fn door, acc ->
        Raster.union(acc, segment_spans(geometry, {door.from, door.to}))
      end)

    spans = walls |> Raster.subtract(openings) |> Raster.union(obstacles) |> Raster.union(shut)
    base = base_rows(map, geometry, opts)

    rows =
      base
      |> Enum.with_index()
      |> Enum.map(fn {row, r} -> Raster.paint(row, Map.get(spans, r, []), 1) end)

    Grid.new(w, h, cells: IO.iodata_to_binary(rows), resolution: res, origin: {ox, oy})
  end

  @doc """
  The cells of a door's opening in `grid`: every cell the segment between
  its jambs touches, except those it touches only at the jambs themselves.
  A planner blocks them when the door closes and unblocks them when it
  opens (on a grid from `grid_from_wdf/2`; an inflated grid should be
  inflated again). `door` is a WDF door (`%{from: {x, y}, to: {x, y}}`).
  """
  @spec door_cells(Grid.t(), door()) :: [Grid.cell()]
  def door_cells(%Grid{} = grid, door) do
    geometry =
      {elem(grid.origin, 0), elem(grid.origin, 1), grid.resolution, grid.width, grid.height}

    Raster.cells(door_spans(geometry, door), grid.width, grid.height)
  end

  @doc """
  The grid with every cell within `radius` (m) of a blocked cell blocked
  too (distances between cell centres; a disc of `radius / resolution`
  cells): a planner may then treat the robot as a point. Works on the
  boundary runs of each row (a separable dilation: each row's blocked runs
  widened by the disc's half-width at each row offset), fast enough for
  maps of millions of cells.
  """
  @spec inflate(Grid.t(), number()) :: Grid.t()
  def inflate(%Grid{} = grid, radius) when radius <= 0, do: grid

  def inflate(%Grid{width: w, height: h, cells: cells, resolution: res} = grid, radius) do
    r = radius / res
    d = floor(r + @eps)
    half = List.to_tuple(for dr <- 0..d, do: floor(:math.sqrt(max(r * r - dr * dr, 0.0)) + @eps))
    runs = List.to_tuple(for <<row::binary-size(w) <- cells>>, do: Raster.runs(row))

    widened =
      for hw <- half |> Tuple.to_list() |> Enum.uniq(), into: %{} do
        {hw,
         runs
         |> Tuple.to_list()
         |> Enum.map(fn row_runs -> for({c0, c1} <- row_runs, do: {c0 - hw, c1 + hw}) end)
         |> List.to_tuple()}
      end

    zero = Raster.fill(0, w)

    rows =
      for row <- 0..(h - 1) do
        spans =
          for dr <- -d..d,
              source = row + dr,
              source >= 0 and source < h,
              span <- elem(widened[elem(half, abs(dr))], source),
              do: span

        Raster.paint(zero, spans, 1)
      end

    %{grid | cells: IO.iodata_to_binary(rows)}
  end

  @doc """
  What a world says of the cells of `grid` (a grid from `grid_from_wdf/2`
  of the same world), as an occupancy grid: its walls, obstacles and
  closed doors occupied (100), the cells of its imported `map_server` map
  as the map has them, the rest unknown (−1). The map builder starts from
  it.
  """
  @spec prior(WDF.t(), Grid.t()) :: OccupancyGrid.t()
  def prior(%WDF{} = wdf, %Grid{width: w, height: h} = grid) do
    {ox, oy} = grid.origin
    raw = base_rows(wdf.grid, {ox, oy, grid.resolution, w, h}, fill: 255, lut: :raw)
    # the grid's blocked cells over the raw map, in C: a warehouse map
    # has 1.7 million cells (seconds cell by cell in Elixir)
    data = GridNif.overlay(IO.iodata_to_binary(raw), grid.cells, 100)

    %OccupancyGrid{
      width: w,
      height: h,
      data: data,
      resolution: grid.resolution,
      origin: grid.origin
    }
  end

  @doc "The number of blocked cells of a grid."
  @spec blocked_count(Grid.t()) :: non_neg_integer()
  def blocked_count(%Grid{cells: cells}),
    do: length(:binary.matches(cells, <<1>>))

  ## frame

  defp check_map!(nil, _opts), do: :ok

  defp check_map!(%RosMap{origin: {_, _, yaw}} = map, opts) do
    if abs(yaw) > 1.0e-9,
      do:
        raise(
          ArgumentError,
          "#{map.file}: the map's origin has a yaw of #{yaw} rad; only axis-aligned maps (yaw 0) can be rasterized"
        )

    case Keyword.fetch(opts, :resolution) do
      {:ok, res} when abs(res - map.resolution) > 1.0e-9 ->
        raise ArgumentError,
              "resolution #{res} differs from the occupancy map's #{map.resolution} (#{map.file}); resampling is not supported"

      _ ->
        :ok
    end
  end

  defp frame(wdf, map, res, opts) do
    margin = Keyword.get(opts, :margin, if(map, do: 0.0, else: 0.5))

    {{x0, y0}, {x1, y1}} =
      case Keyword.fetch(opts, :bounds) do
        {:ok, bounds} ->
          bounds

        :error ->
          feature_bounds(wdf, margin)
          |> union_bounds(map_bounds(map))
          |> Kernel.||({{-margin, -margin}, {margin, margin}})
      end

    {ax, ay} =
      case map do
        nil -> {x0, y0}
        %RosMap{origin: {mx, my, _}} -> {mx, my}
      end

    ox = ax + floor((x0 - ax) / res + @eps) * res
    oy = ay + floor((y0 - ay) / res + @eps) * res
    w = max(ceil((x1 - ox) / res - @eps), 1)
    h = max(ceil((y1 - oy) / res - @eps), 1)
    {{ox, oy}, w, h}
  end

  defp feature_bounds(wdf, margin) do
    points =
      Enum.flat_map(wdf.walls, fn {a, b} -> [a, b] end) ++
        Enum.flat_map(wdf.obstacles ++ wdf.rooms ++ wdf.corridors ++ wdf.areas, & &1.polygon) ++
        Enum.flat_map(wdf.doors, &[&1.from, &1.to]) ++
        Enum.map(wdf.beacons, & &1.at) ++
        Enum.map(wdf.waypoints, fn %{at: at} -> {elem(at, 0), elem(at, 1)} end)

    case points do
      [] ->
        nil

      _ ->
        {xs, ys} = Enum.unzip(points)

        {{Enum.min(xs) - margin, Enum.min(ys) - margin},
         {Enum.max(xs) + margin, Enum.max(ys) + margin}}
    end
  end

  defp map_bounds(nil), do: nil

  defp map_bounds(%RosMap{origin: {x, y, _}, resolution: r, width: w, height: h}),
    do: {{x, y}, {x + w * r, y + h * r}}

  defp union_bounds(nil, b), do: b
  defp union_bounds(a, nil), do: a

  defp union_bounds({{ax0, ay0}, {ax1, ay1}}, {{bx0, by0}, {bx1, by1}}),
    do: {{min(ax0, bx0), min(ay0, by0)}, {max(ax1, bx1), max(ay1, by1)}}

  ## layers

  defp closed_doors(wdf, opts) do
    case Keyword.fetch(opts, :closed) do
      {:ok, names} -> MapSet.new(names)
      :error -> wdf.doors |> Enum.reject(& &1.open) |> MapSet.new(& &1.name)
    end
  end

  defp segment_spans(geometry, {a, b}),
    do: Raster.segment(Raster.to_cells(geometry, a), Raster.to_cells(geometry, b))

  # the door segment short of its jambs by a millionth of a cell: the cells
  # it crosses, not those it only touches at its ends
  defp door_spans(geometry, %{from: from, to: to}) do
    {u1, v1} = Raster.to_cells(geometry, from)
    {u2, v2} = Raster.to_cells(geometry, to)
    len = :math.sqrt((u2 - u1) ** 2 + (v2 - v1) ** 2)

    if len < 2.0e-6 do
      %{}
    else
      {eu, ev} = {(u2 - u1) / len * 1.0e-6, (v2 - v1) / len * 1.0e-6}
      Raster.segment({u1 + eu, v1 + ev}, {u2 - eu, v2 - ev})
    end
  end

  # the occupancy map's cells where the grid has them (blocked or
  # passable, or as they are with `lut: :raw`), the rest `fill` (passable)
  defp base_rows(nil, {_ox, _oy, _res, w, h}, opts),
    do: List.duplicate(Raster.fill(Keyword.get(opts, :fill, 0), w), h)

  defp base_rows(%RosMap{} = map, {ox, oy, res, w, h}, opts) do
    {mx, my, _} = map.origin
    col0 = round((mx - ox) / res)
    row0 = round((my - oy) / res)

    converted =
      case Keyword.get(opts, :lut) do
        :raw ->
          map.data

        nil ->
          lut(Keyword.get(opts, :unknown, :blocked), Keyword.get(opts, :occupied_threshold, 50))
          |> then(&convert(map.data, &1))
      end

    fill = Keyword.get(opts, :fill, 0)
    zero = Raster.fill(fill, w)

    for r <- 0..(h - 1) do
      mr = r - row0

      if mr < 0 or mr >= map.height do
        zero
      else
        src = binary_part(converted, mr * map.width, map.width)
        # the part of the map row inside the grid's columns
        first = max(0, -col0)
        last = min(map.width, w - col0)

        if last <= first do
          zero
        else
          left = col0 + first
          middle = binary_part(src, first, last - first)
          right = w - left - byte_size(middle)
          IO.iodata_to_binary([Raster.fill(fill, left), middle, Raster.fill(fill, right)])
        end
      end
    end
  end

  defp lut(unknown, threshold) do
    for v <- 0..255 do
      signed = if v > 127, do: v - 256, else: v

      cond do
        signed == -1 -> if unknown == :free, do: 0, else: 1
        signed >= threshold -> 1
        true -> 0
      end
    end
    |> List.to_tuple()
  end

  defp convert(data, lut), do: for(<<v <- data>>, into: <<>>, do: <<elem(lut, v)>>)
end
