defmodule ThinkingCap.Navigation.PathPlanner do
  @moduledoc """
  Plans a robot's path on what it knows of the world, and repairs it as
  that changes: a cost map from an occupancy grid (`set_map/2`), searched
  with D* Lite (`ThinkingCap.Navigation.DStarLite`) from the robot's cell
  to the goal's, repaired in place when the map or the robot's position
  changes instead of searched again from scratch.

  **The cost map.** Cells of occupancy at least `threshold` (default 50)
  are obstacles, grown by `radius` (the robot's, plus a margin) so that
  the robot may be planned as a point; unknown cells are free
  (optimistic planning: a goal in unexplored space may be planned to, and
  the path is repaired when the space turns out not to be free). Big
  maps are planned on coarser cells: `resolution` (default 0.05 m) sets
  the planning cell, a whole multiple of the map's (a block is an
  obstacle if any of its cells is).

  **The cost band.** With `band` (m, default 0: none), the cells within
  `band` beyond the grown obstacles cost more to cross: `band_cost`
  (2 to 255, default 200) at the obstacle's edge, falling as the square
  of the way left to 0 at the band's outer edge (see
  `ThinkingCap.Navigation.Grid` for what a cell's cost does to a step).
  A plan then takes a gap that leaves the robot little room only when
  the way round is much longer, and keeps to the middle of a passage a
  little wider than the robot: the behaviours that drive it slow down
  and turn back near obstacles, and a gap the planner fits by a
  centimetre or two, they may refuse. D* Lite repairs a change of cost
  as it repairs a change of obstacles; `distances/3` counts the costs
  too (metres as the band weighs them).

  **Repairs.** A new map in the same frame changes only the cells whose
  blocked state differs. The next `plan/3` to the same goal repairs the
  last search: D* Lite finds those cells itself, in C, by comparing the
  new cost map with its own copy (`DStarLite.update_grid/3`), and
  repairs the path from there. A new frame (the map grew) or a new goal
  starts a new search; so, to the same goal, do more than `max_changes`
  changed cells. A start that jumped more than `max_jump` metres (a
  localizer that found the robot elsewhere) is repaired too, and
  recorded as a `:jump`: the distances to the goal that the search knows
  still hold, and a new D* Lite search would find them again. (In `mix
  tc.bench nav_unknown` on the warehouse map, 14 such jumps cost 206 ms
  of CPU repaired and 328 ms searched anew; one of them, where the robot
  was found 2 m from where the search had grown, 85 and 89 ms, with A*
  from scratch 30 ms.)

  **Keeping clear.** The planner also keeps the distance field of the
  obstacles (before they are grown): `clearance/2` and `in_sight?/3` read
  it. With `clearance` (m), `keep_clear/2` moves a path's points away
  from the obstacles up to that distance where there is room
  (`ThinkingCap.Navigation.KeepClear`): a path down the middle of a
  corridor and through the middle of a door, not along the wall at the
  robot's radius.

  Every `plan/3` records what it did in `last`: `%{kind: :initial |
  :repair | :jump | :restart, us: microseconds, cpu_us: microseconds, expanded:
  vertices, changed: cells}` (`:jump` a repair after the start jumped, `:restart` a new
  search to the goal of the last one; `us`, on the wall clock, covers the robot's move, finding and
  repairing the changed cells, and the search; `cpu_us` is the CPU time
  the search's C code took for all that, `DStarLite.cpu_time/1`); with
  `compare: true` also `astar_us` and `astar_cpu_us`, the wall-clock and
  CPU time A* takes from scratch on the same grid (for benchmarks: it
  costs that much more).
  """

  alias ThinkingCap.Navigation.{AStar, DStarLite, Grid, KeepClear, OccupancyGrid}
  alias ThinkingCap.Navigation.Core.{Cost, GridNif}
  require Cost

  defstruct radius: 0.25,
            band: 0.0,
            band_cost: 200,
            threshold: 50,
            resolution: 0.05,
            max_changes: 20_000,
            max_jump: 1.5,
            compare: false,
            clearance: nil,
            grid: nil,
            field: nil,
            version: nil,
            pending: :reset,
            search: nil,
            goal: nil,
            last: nil

  @type point :: {number(), number()}
  @type t :: %__MODULE__{
          radius: float(),
          band: float(),
          band_cost: 2..255,
          threshold: 0..100,
          resolution: float(),
          max_changes: pos_integer(),
          max_jump: float(),
          compare: boolean(),
          clearance: float() | nil,
          grid: Grid.t() | nil,
          field: KeepClear.field() | nil,
          version: term(),
          pending: :none | {:changed, [binary()] | :scan} | :reset,
          search: DStarLite.t() | nil,
          goal: Grid.cell() | nil,
          last: map() | nil
        }
  @type error ::
          :no_map
          | :goal_outside_map
          | :goal_blocked
          | :start_outside_map
          | :start_blocked
          | :no_path

  @doc """
  A planner without a map. Options: `radius`, `band`, `band_cost`,
  `threshold`, `resolution`, `max_changes`, `max_jump` (m, default 1.5: a
  longer move of the start is recorded as a `:jump`), `compare`,
  `clearance`.
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    band_cost = Keyword.get(opts, :band_cost, 200)

    unless is_integer(band_cost) and band_cost in 2..255,
      do: raise(ArgumentError, "band_cost: an integer from 2 to 255, got #{inspect(band_cost)}")

    band = Keyword.get(opts, :band, 0.0)

    unless is_number(band) and band >= 0,
      do: raise(ArgumentError, "band: a number of metres >= 0, got #{inspect(band)}")

    struct!(
      __MODULE__,
      Keyword.take(opts, [
        :radius,
        :band,
        :band_cost,
        :threshold,
        :resolution,
        :max_changes,
        :max_jump,
        :compare,
        :clearance
      ])
    )
  end

  @doc """
  Takes a map (its `version` tells an update from the same map seen
  again, which is ignored). Returns the planner with its cost map
  rebuilt and the changes queued for the next `plan/3`.
  """
  @spec set_map(t(), OccupancyGrid.t()) :: t()
  def set_map(%__MODULE__{version: v} = planner, %OccupancyGrid{version: v} = _map)
      when v != nil and v != 0,
      do: planner

  def set_map(%__MODULE__{} = planner, %OccupancyGrid{} = map) do
    {grid, distances, diff} = grids(planner, map)

    %{
      planner
      | grid: grid,
        field: %{grid: grid, distances: distances},
        version: map.version,
        pending: changes(planner, grid, diff)
    }
  end

  @doc """
  The cost map of an occupancy grid (see the moduledoc): a planning grid
  whose blocked cells are obstacles grown by the planner's radius.
  """
  @spec cost_grid(t(), OccupancyGrid.t()) :: Grid.t()
  def cost_grid(%__MODULE__{} = planner, %OccupancyGrid{} = map),
    do: elem(grids(%{planner | grid: nil}, map), 0)

  # the cost map, the distances to the blocked cells before they are
  # grown (one distance transform for both), and the cells where the
  # cost map differs from the planner's last one (listed while it is
  # written; nil without a last one of that size and frame)
  defp grids(planner, %OccupancyGrid{width: w, height: h} = map) do
    k = max(1, round(planner.resolution / map.resolution))
    blocked = GridNif.blocked(map.data, planner.threshold, 0)
    {cw, ch, coarse} = if k == 1, do: {w, h, blocked}, else: GridNif.shrink(blocked, w, h, k)
    res = map.resolution * k
    old = planner.grid

    old_cells =
      if old != nil and
           {old.width, old.height, old.origin, old.resolution} == {cw, ch, map.origin, res},
         do: old.cells

    {cells, diff, distances} =
      GridNif.cost_map(
        coarse,
        cw,
        ch,
        planner.radius / res,
        planner.band / res,
        planner.band_cost,
        old_cells,
        planner.max_changes
      )

    {Grid.new(cw, ch, cells: cells, resolution: res, origin: map.origin), distances, diff}
  end

  @doc """
  A path (world points, from the robot to the goal) moved away from the
  obstacles up to the planner's `clearance` where there is room
  (`ThinkingCap.Navigation.KeepClear.push/3`); the ends stay. The path as
  given without a `clearance` or a map.
  """
  @spec keep_clear(t(), [point()]) :: [point()]
  def keep_clear(%__MODULE__{clearance: c, field: field} = planner, path)
      when is_number(c) and field != nil,
      do: KeepClear.push(path, field, prefer: c, radius: planner.radius)

  def keep_clear(%__MODULE__{}, path), do: path

  @doc """
  How far (m) a point is from the nearest obstacle of the map (before it
  is grown); `0.0` without a map.
  """
  @spec clearance(t(), point()) :: float()
  def clearance(%__MODULE__{field: nil}, _point), do: 0.0
  def clearance(%__MODULE__{field: field}, point), do: KeepClear.clearance(field, point)

  @doc """
  Whether the straight line between two points crosses no obstacle of
  the map (before it is grown); `true` without a map.
  """
  @spec in_sight?(t(), point(), point()) :: boolean()
  def in_sight?(%__MODULE__{field: nil}, _a, _b), do: true

  def in_sight?(%__MODULE__{field: field}, a, b),
    do: KeepClear.segment_clearance(field, a, b) >= field.grid.resolution

  # whether the search must start anew (:reset: a new frame), may have
  # cells to repair (:changed) or has nothing new (:none)
  # (:changed: the cells that may differ from the search's grid, or
  # :scan, all of them)
  defp changes(%{grid: nil}, _grid, _diff), do: :reset
  defp changes(%{pending: :reset}, _grid, _diff), do: :reset
  defp changes(planner, _grid, <<>>), do: planner.pending
  defp changes(_planner, _grid, nil), do: :reset
  defp changes(_planner, _grid, :too_many), do: {:changed, :scan}
  defp changes(%{pending: {:changed, :scan}}, _grid, _diff), do: {:changed, :scan}
  defp changes(%{pending: {:changed, hints}}, _grid, diff), do: {:changed, [diff | hints]}
  defp changes(%{pending: :none}, _grid, diff), do: {:changed, [diff]}

  @doc """
  The path from `from` to `goal` (world points) on the current map:
  `{:ok, points, planner}`, the centres of the path's cells from the
  robot's to the goal's, or `{:error, reason, planner}`:

    * `:no_map` - no map yet;
    * `:start_outside_map`, `:goal_outside_map` - a point off the map;
    * `:goal_blocked` - the goal lies in an obstacle (or within the
      robot's radius of one) with no free cell within `radius`;
    * `:no_path` - no way to the goal on the map as known.

    * `:start_blocked` - the robot is deep in an obstacle as mapped.

  A start within the robot's radius of an obstacle (a robot brushing a
  wall) plans from the nearest free cell within twice the radius.
  """
  @spec plan(t(), point(), point()) :: {:ok, [point()], t()} | {:error, error(), t()}
  def plan(%__MODULE__{grid: nil} = planner, _from, _goal), do: {:error, :no_map, planner}

  def plan(%__MODULE__{grid: grid} = planner, from, goal) do
    with {:ok, start} <- cell(grid, from, :start_outside_map, 2 * planner.radius),
         {:ok, target} <- cell(grid, goal, :goal_outside_map, planner.radius) do
      search(planner, start, target)
    else
      {:error, :blocked, :start_outside_map} -> {:error, :start_blocked, planner}
      {:error, :blocked, :goal_outside_map} -> {:error, :goal_blocked, planner}
      {:error, reason} -> {:error, reason, planner}
    end
  end

  @doc """
  The length (m) of the shortest path on the cost map from `from` to
  each of `points` (with a `band`, its cost: its length with the steps
  through the band counted longer), in one search: a list in the order of `points`, `nil`
  for a point no path reaches, off the map, or in an obstacle with no free
  cell within the planner's radius. All `nil` without a map or when the
  robot's cell is blocked. The search stops once every point is reached.
  """
  @spec distances(t(), point(), [point()]) :: [float() | nil]
  def distances(%__MODULE__{grid: nil}, _from, points), do: Enum.map(points, fn _ -> nil end)

  def distances(%__MODULE__{grid: grid} = planner, from, points) do
    cells = Enum.map(points, &free_cell(grid, &1, planner.radius))

    case free_cell(grid, from, 2 * planner.radius) do
      nil ->
        Enum.map(points, fn _ -> nil end)

      start ->
        targets = for cell <- cells, cell != nil, do: cell
        units = GridNif.costs(grid.cells, grid.width, grid.height, start, targets)
        metres = Map.new(Enum.zip(targets, units))
        scale = grid.resolution / Cost.straight()

        Enum.map(cells, fn
          nil -> nil
          cell -> with u when is_integer(u) <- metres[cell], do: u * scale, else: (_ -> nil)
        end)
    end
  end

  defp free_cell(grid, point, within) do
    case cell(grid, point, :outside, within) do
      {:ok, cell} -> cell
      _ -> nil
    end
  end

  # the point's cell, or the nearest free cell within `within` metres
  defp cell(grid, point, outside, within) do
    cell = Grid.cell_of(grid, point)

    cond do
      not Grid.inside?(grid, cell) -> {:error, outside}
      Grid.passable?(grid, cell) -> {:ok, cell}
      free = nearest_free(grid, cell, ceil(within / grid.resolution)) -> {:ok, free}
      true -> {:error, :blocked, outside}
    end
  end

  defp nearest_free(grid, {col, row}, rings) do
    Enum.find_value(1..max(rings, 1), fn r ->
      ring = for dc <- -r..r, dr <- -r..r, max(abs(dc), abs(dr)) == r, do: {col + dc, row + dr}

      case Enum.filter(ring, &Grid.passable?(grid, &1)) do
        [] -> nil
        free -> Enum.min_by(free, fn {c, w} -> {(c - col) ** 2 + (w - row) ** 2, c, w} end)
      end
    end)
  end

  defp search(planner, start, target) do
    started = System.monotonic_time(:microsecond)
    cpu_before = cpu_before(planner)
    {kind, dstar, changed} = prepare(planner, start, target)
    result = DStarLite.plan(dstar)
    us = System.monotonic_time(:microsecond) - started
    dstar = elem(result, tuple_size(result) - 1)
    cpu_before = if kind in [:repair, :jump], do: cpu_before, else: 0
    cpu_us = div(DStarLite.cpu_time(dstar) - cpu_before, 1000)
    last = %{kind: kind, us: us, cpu_us: cpu_us, expanded: dstar.expanded, changed: changed}

    last =
      if planner.compare,
        do: Map.merge(last, astar_time(planner.grid, start, target)),
        else: last

    planner = %{planner | search: dstar, goal: target, pending: :none, last: last}

    case result do
      {:ok, cells, _} -> {:ok, Enum.map(cells, &Grid.centre(planner.grid, &1)), planner}
      {:error, :no_path, _} -> {:error, :no_path, planner}
    end
  end

  # a repair of the last search to the same goal in the same frame: the
  # robot's move, then the cells that differ between the search's grid
  # and the planner's (found and repaired in C); a new search when there
  # is none to repair, or when so many cells changed that searching
  # anew is cheaper
  defp prepare(
         %{search: %DStarLite{} = search, goal: target, pending: pending} = planner,
         start,
         target
       )
       when pending != :reset do
    kind = if jumped?(planner, search.start, start), do: :jump, else: :repair
    search = DStarLite.move_start(search, start)

    if pending == :none do
      {kind, search, 0}
    else
      {:changed, hints} = pending
      hint = if hints == :scan, do: nil, else: IO.iodata_to_binary(hints)

      case DStarLite.update_grid(search, planner.grid, planner.max_changes, hint) do
        {:ok, search, changed} -> {kind, search, changed}
        {:too_many, _changed, _search} -> restart(planner, start, target)
      end
    end
  end

  defp prepare(planner, start, target),
    do: {:initial, DStarLite.new(planner.grid, start, target), 0}

  defp restart(planner, start, target),
    do: {:restart, DStarLite.new(planner.grid, start, target), 0}

  defp jumped?(planner, {c0, r0}, {c1, r1}),
    do: max(abs(c1 - c0), abs(r1 - r0)) * planner.grid.resolution > planner.max_jump

  defp cpu_before(%{search: %DStarLite{} = search, pending: pending}) when pending != :reset,
    do: DStarLite.cpu_time(search)

  defp cpu_before(_planner), do: 0

  # A* from scratch as `AStar.plan/3` runs it on a passable start and goal
  defp astar_time(grid, start, target) do
    if Grid.passable?(grid, start) and Grid.passable?(grid, target) and start != target do
      {us, {ns, _}} =
        :timer.tc(fn -> GridNif.astar_cpu(grid.cells, grid.width, grid.height, start, target) end)

      %{astar_us: us, astar_cpu_us: div(ns, 1000)}
    else
      {us, _} = :timer.tc(fn -> AStar.plan(grid, start, target) end)
      %{astar_us: us, astar_cpu_us: 0}
    end
  end
end
