defmodule ThinkingCap.Navigation.DStarLite do
  @moduledoc """
  Incremental replanning on a `ThinkingCap.Navigation.Grid` with D* Lite
  (S. Koenig and M. Likhachev, "D* Lite", AAAI 2002: the optimized version
  of their figure 4), for a robot that moves towards a goal while the
  cells around it change.

  The cost model is `ThinkingCap.Navigation.AStar`'s: 8-connected, a
  straight step costs 1 and a diagonal one √2, no corner cutting (a
  diagonal step needs both orthogonal cells it passes between passable),
  octile heuristic, exact integer arithmetic. Every plan is optimal: it
  costs what A* finds from scratch on the current grid.

  The search runs backwards, from the goal towards the robot: g-scores
  are distances to the goal, so when cells change only the vertices whose
  distance changed, and that matter to the robot's current cell, are
  processed again; when the robot moves (`move_start/2`), the key modifier
  `km` keeps the queued priorities valid without reordering the queue.

  Ties between vertices of equal priority are broken as A* breaks them,
  towards the robot: the paper breaks them towards the goal, which in
  open space (where the octile distance is exact) processes every cell
  of every shortest path before the robot's, and after a jump of the
  robot a whole parallelogram of them. Vertices whose distance grew are
  still processed first among equals, which keeps every plan optimal.
  A plan walks the path again only up to where the last one is
  unchanged.

      state = DStarLite.new(grid, start, goal)
      {:ok, path, state} = DStarLite.plan(state)
      state = DStarLite.move_start(state, Enum.at(path, 3))
      state = DStarLite.update_cells(state, [{{12, 7}, true}])   # an obstacle
      {:ok, path, state} = DStarLite.plan(state)                # repaired

  ## The state is single-use

  The search lives in C (`c_src/tc_plan.c`: g- and rhs-values and an
  indexed heap of the inconsistent vertices, in a NIF resource shared by a
  state and the states derived from it), so only the state returned by
  the last call is valid: passing an older one raises `ArgumentError`.
  An update that only blocks cells next to vertices the search never
  reached (their rhs is infinite) costs next to nothing: their distances
  cannot fall. Costs must stay below 2^22 cells (the integer units are
  2^-36 cell; infinity is 2^58 units).
  """

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Core.GridNif

  @enforce_keys [:grid, :start, :goal, :store, :version]
  defstruct [:grid, :start, :goal, :store, :version, expanded: 0]

  @typedoc """
  A D* Lite search: the `grid` as it is now, the robot's cell `start`, the
  `goal`, and `expanded`, the number of vertices the last `plan/1`
  processed (made consistent). Other fields are internal.
  """
  @type t :: %__MODULE__{
          grid: Grid.t(),
          start: Grid.cell(),
          goal: Grid.cell(),
          store: {reference(), :atomics.atomics_ref()},
          version: pos_integer(),
          expanded: non_neg_integer()
        }

  @doc """
  A search from `start` to `goal` on `grid` (both cells inside the grid;
  either may be blocked, `plan/1` then finds no path). Nothing is searched
  until `plan/1`.
  """
  @spec new(Grid.t(), Grid.cell(), Grid.cell()) :: t()
  def new(%Grid{width: w, height: h} = grid, start, goal) do
    inside!(grid, start)
    inside!(grid, goal)
    version = :atomics.new(1, signed: false)
    :atomics.put(version, 1, 1)
    dsl = GridNif.dsl_new(grid.cells, w, h, start, goal)
    %__MODULE__{grid: grid, start: start, goal: goal, store: {dsl, version}, version: 1}
  end

  @doc """
  Computes (or repairs) the shortest path from the current start to the
  goal: `{:ok, path, state}` with the path's cells from start to goal, or
  `{:error, :no_path, state}` (also when the start or the goal is blocked).
  The path's cost is `ThinkingCap.Navigation.AStar.cost/1` of it; the
  state's `expanded` counts the vertices this call processed.
  """
  @spec plan(t()) :: {:ok, [Grid.cell()], t()} | {:error, :no_path, t()}
  def plan(%__MODULE__{} = state) do
    state = next_version(state)

    case GridNif.dsl_plan(elem(state.store, 0)) do
      {:ok, path, expanded} -> {:ok, path, %{state | expanded: expanded}}
      {:error, :no_path, expanded} -> {:error, :no_path, %{state | expanded: expanded}}
    end
  end

  @doc """
  Cells change: each `{cell, blocked?}` blocks (`true`) or frees (`false`)
  a cell (cells outside the grid and cells that already are so are
  ignored; a later change of the same cell wins). The vertices whose
  outgoing edges changed (the cells and their 8 neighbours) get their
  rhs-values recomputed and are queued if that made them inconsistent;
  the next `plan/1` repairs the path from there. The NIF reads, filters
  and applies the list in one call.
  """
  @spec update_cells(t(), [{Grid.cell(), boolean()}]) :: t()
  def update_cells(%__MODULE__{} = state, changes) when is_list(changes) do
    state = next_version(state)

    case GridNif.dsl_update(elem(state.store, 0), changes) do
      {0, nil} -> state
      {_n, cells} -> %{state | grid: %{state.grid | cells: cells}}
    end
  end

  @doc """
  The grid is now `grid` (the same size, origin and resolution): the
  search finds the cells that differ from its own copy and repairs them
  as `update_cells/2` does, all in C, without a list of changes. Returns
  `{:ok, state, changed}` with the number of cells that changed, or
  `{:too_many, changed, state}` when more than `max_changes` did: the
  search is then left on its old grid (a search from scratch is cheaper
  than such a repair), and `changed` counts up to `max_changes + 1`.

  `hint`, when given, lists (as native 32-bit cell indices, repeats
  allowed) every cell that may differ: the search then looks at those
  only, not at the whole grid. A cost map's builder can list them as it
  writes the grid (`ThinkingCap.Navigation.PathPlanner` does).
  """
  @spec update_grid(t(), Grid.t(), non_neg_integer() | :infinity, binary() | nil) ::
          {:ok, t(), non_neg_integer()} | {:too_many, pos_integer(), t()}
  def update_grid(state, grid, max_changes \\ :infinity, hint \\ nil)

  def update_grid(
        %__MODULE__{grid: %Grid{width: w, height: h}} = state,
        %Grid{} = grid,
        max,
        hint
      )
      when grid.width == w and grid.height == h do
    state = next_version(state)
    max = if max == :infinity, do: w * h, else: max
    store = elem(state.store, 0)

    result =
      if hint,
        do: GridNif.dsl_sync(store, grid.cells, max, hint),
        else: GridNif.dsl_sync(store, grid.cells, max)

    case result do
      {:ok, n} -> {:ok, %{state | grid: grid}, n}
      {:too_many, n} -> {:too_many, n, state}
    end
  end

  def update_grid(%__MODULE__{grid: old}, %Grid{} = grid, _max, _hint),
    do:
      raise(
        ArgumentError,
        "grid of #{grid.width}×#{grid.height} for a search on #{old.width}×#{old.height}"
      )

  @doc """
  The robot is now at `start` (a cell inside the grid, usually the next
  cells of the last path): the key modifier grows by the heuristic
  distance between the old and the new start, which keeps every queued key
  a lower bound of its new value. A queued vertex whose key was such a
  bound is queued again with its key computed anew when it comes first
  (the optimized D* Lite), so the search is as good after a jump of any
  length: the distances to the goal found so far are kept.
  """
  @spec move_start(t(), Grid.cell()) :: t()
  def move_start(%__MODULE__{} = state, start) do
    state = next_version(state)
    inside!(state.grid, start)
    :ok = GridNif.dsl_move_start(elem(state.store, 0), start)
    %{state | start: start}
  end

  @doc """
  The CPU time (ns) that the calls on this search (`new/3` and every call
  on the states derived from it) have taken, on whichever threads they
  ran. Unlike the wall clock, it leaves out the time the operating system
  gave to other threads meanwhile, so on a busy machine it still says
  what the search cost. Reading it does not change the state.
  """
  @spec cpu_time(t()) :: non_neg_integer()
  def cpu_time(%__MODULE__{store: {dsl, _}}), do: GridNif.dsl_cpu_ns(dsl)

  @doc """
  The entries in the search's queue. A vertex whose key changes is
  queued again rather than moved, and its old entry left stale; stale
  entries are dropped when they reach the top or when the queue is
  full, so that a long run of repairs keeps the queue about the size of
  the search's frontier.
  """
  @spec queued(t()) :: non_neg_integer()
  def queued(%__MODULE__{store: {dsl, _}}), do: GridNif.dsl_queued(dsl)

  defp next_version(%__MODULE__{store: {_dsl, a}, version: v} = state) do
    case :atomics.compare_exchange(a, 1, v, v + 1) do
      :ok ->
        %{state | version: v + 1}

      _ ->
        raise ArgumentError,
              "stale D* Lite state: pass the state returned by the last call on this search"
    end
  end

  defp inside!(grid, cell) do
    unless Grid.inside?(grid, cell),
      do:
        raise(
          ArgumentError,
          "cell #{inspect(cell)} outside the #{grid.width}×#{grid.height} grid"
        )
  end
end
