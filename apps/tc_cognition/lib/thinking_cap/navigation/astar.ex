defmodule ThinkingCap.Navigation.AStar do
  @moduledoc """
  Optimal path planning on a `ThinkingCap.Navigation.Grid` with A*.

  Moves are 8-connected: a straight step costs 1, a diagonal step √2
  (times more in a grid's costly cells, see `ThinkingCap.Navigation.Grid`
  and `cost/2`), and a diagonal step is allowed only when both orthogonal
  cells it passes between are passable (no corner cutting). The heuristic is the octile
  distance, which is consistent for these moves, so the path found is
  optimal. Costs are in cells; `path_length_m/2` turns a path into metres.

  The search runs in exact integer arithmetic (see `cost/1`'s note), in
  C (`c_src/tc_plan.c`, on a dirty scheduler): scratch memory the search
  touches only where it goes, a binary heap on f-scores with ties to the
  deepest cell, and the path read back from the goal along optimal
  predecessors.

      {:ok, %{path: path, cost: cost, expanded: n}} = AStar.plan(grid, {1, 1}, {40, 12})
  """

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Core.{Cost, GridNif}
  require Cost

  @type cell :: Grid.cell()
  @type result :: %{path: [cell()], cost: float(), expanded: non_neg_integer()}
  @type error :: :no_path | :blocked_start | :blocked_goal

  @doc """
  The cheapest path from `start` to `goal` (both cells, both included in
  `path`; the shortest on a grid without costly cells), its length in
  cells `cost` (`cost/2` gives the cost the search minimised) and the
  number of cells `expanded` (closed) by the search.

  Errors: `:blocked_start` or `:blocked_goal` when that cell is outside the
  grid or blocked, `:no_path` when the goal cannot be reached. There are no
  options yet; `opts` is accepted for future ones.
  """
  @spec plan(Grid.t(), cell(), cell(), keyword()) :: {:ok, result()} | {:error, error()}
  def plan(%Grid{} = grid, start, goal, opts \\ []) when is_list(opts) do
    cond do
      not Grid.passable?(grid, start) -> {:error, :blocked_start}
      not Grid.passable?(grid, goal) -> {:error, :blocked_goal}
      true -> search(grid, start, goal)
    end
  end

  @doc """
  `plan/4` between two world points: each is mapped to its cell with
  `Grid.cell_of/2`, and the path comes back as the world positions of its
  cells' centres (`Grid.centre/2`). The result also holds `cells` (the
  path as cells) and `length_m` (`path_length_m/2`); `cost` stays in cells.
  """
  @spec plan_world(Grid.t(), {number(), number()}, {number(), number()}, keyword()) ::
          {:ok,
           %{
             path: [{float(), float()}],
             cells: [cell()],
             cost: float(),
             length_m: float(),
             expanded: non_neg_integer()
           }}
          | {:error, error()}
  def plan_world(%Grid{} = grid, from, to, opts \\ []) do
    with {:ok, %{path: cells} = result} <-
           plan(grid, Grid.cell_of(grid, from), Grid.cell_of(grid, to), opts) do
      {:ok,
       Map.merge(result, %{
         path: Enum.map(cells, &Grid.centre(grid, &1)),
         cells: cells,
         length_m: path_length_m(grid, cells)
       })}
    end
  end

  @doc """
  The length in metres of a path of cells: the sum of the distances between
  consecutive cell centres (1 or √2 cells for a step) times the grid's
  resolution.
  """
  @spec path_length_m(Grid.t(), [cell()]) :: float()
  def path_length_m(%Grid{resolution: r}, path), do: cost(path) * r

  @doc """
  The length in cells of a path of cells (the sum of the distances between
  consecutive cells; for the paths the planners return, straight steps
  count 1 and diagonal steps √2). The planners compare costs exactly in
  integer units of 2^-36 cell (√2 rounded to that grid), then report
  them with this function, so equal costs are equal floats.
  """
  @spec cost([cell()]) :: float()
  def cost([]), do: 0.0

  def cost([{_, _} | _] = path) do
    if adjacent_steps?(path),
      do: Cost.path_cost(path),
      else: path |> Enum.chunk_every(2, 1, :discard) |> Enum.map(&step/1) |> Enum.sum()
  end

  @doc """
  The cost in cells of a path of adjacent cells on `grid`, the cost the
  planners minimise: each step's length (1 or √2) times `1 + (p(a) +
  p(b)) / 16` for the cells' bytes `a` and `b` (see
  `ThinkingCap.Navigation.Grid`). Equal to `cost/1` on a grid without
  costs; `nil` when the path enters a blocked cell or leaves the grid.
  """
  @spec cost(Grid.t(), [cell()]) :: float() | nil
  def cost(%Grid{}, []), do: 0.0

  def cost(%Grid{cells: cells, width: w, height: h}, path) do
    case Cost.units(cells, w, h, path) do
      nil -> nil
      units -> units / Cost.straight()
    end
  end

  defp adjacent_steps?([_]), do: true

  defp adjacent_steps?([{c1, r1}, {c2, r2} = b | rest]),
    do: abs(c1 - c2) <= 1 and abs(r1 - r2) <= 1 and adjacent_steps?([b | rest])

  defp step([{c1, r1}, {c2, r2}]), do: :math.sqrt((c1 - c2) * (c1 - c2) + (r1 - r2) * (r1 - r2))

  ## The search

  defp search(%Grid{} = grid, start, goal) do
    if start == goal do
      {:ok, %{path: [start], cost: 0.0, expanded: 1}}
    else
      case GridNif.astar(grid.cells, grid.width, grid.height, start, goal) do
        {:ok, path, _units, expanded} ->
          {:ok, %{path: path, cost: Cost.path_cost(path), expanded: expanded}}

        {:error, :no_path, _expanded} ->
          {:error, :no_path}
      end
    end
  end
end
