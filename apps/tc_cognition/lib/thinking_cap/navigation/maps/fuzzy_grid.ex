defmodule ThinkingCap.Navigation.Maps.FuzzyGrid do
  @moduledoc """
  A fuzzy grid map (Oriolo, Ulivi & Vendittelli, as used by ThinkingCap):
  every cell carries two independent degrees in [0, 1], how much it is
  believed **empty** (`E`) and how much **occupied** (`O`), gathered from
  range readings; unlike a probability they need not add up to one, so the
  map tells "seen empty and occupied" (ambiguous: `E ∧ O`) from "never
  seen" (indeterminate: `¬E ∧ ¬O`).

  A reading contributes, along its beam (the cells a ray from the sensor
  crosses, Amanatides & Woo's traversal):

    * to the cells before its end, an empty degree `k_empty · fade(d)`;
    * to the cell of its end (if it is an echo, below `range_max`), an
      occupied degree `k_occupied · fade(r)`,

  where `fade(d) = 1 − fade · d / range_max` makes far readings count less
  (defaults: `k_empty` 0.3, `k_occupied` 0.5, `fade` 0.5). Within one scan
  a cell takes the largest contribution of its beams (fuzzy union, `max`);
  the map aggregates scans with the algebraic sum (the fuzzy union
  `a ∨ b = a + b − a·b`), so evidence accumulates towards 1 as readings
  agree.

  The occupied-ness used for planning is `O ∧ ¬E = min(O, 1 − E)` (Zadeh's
  intersection and complement): a cell is an obstacle when it was seen
  occupied and not seen empty.

  Scans and sensor poses are as in `ThinkingCap.Navigation.Maps.LogOdds`;
  only observed cells are stored.
  """

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Maps.{Ray, Sparse}

  @enforce_keys [:width, :height]
  defstruct [
    :width,
    :height,
    resolution: 0.05,
    origin: {0.0, 0.0},
    k_empty: 0.3,
    k_occupied: 0.5,
    fade: 0.5,
    cells: %{}
  ]

  @type t :: %__MODULE__{
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float()},
          k_empty: float(),
          k_occupied: float(),
          fade: float(),
          cells: %{non_neg_integer() => {float(), float()}}
        }

  @doc """
  An unobserved `width` × `height` map. Options: `resolution` (default
  0.05), `origin` (default `{0, 0}`), `k_empty`, `k_occupied`, `fade`.
  """
  @spec new(pos_integer(), pos_integer(), keyword()) :: t()
  def new(width, height, opts \\ []) do
    fields = Keyword.take(opts, [:origin, :k_empty, :k_occupied, :fade])

    struct!(
      %__MODULE__{width: width, height: height},
      [{:resolution, Keyword.get(opts, :resolution, 0.05) * 1.0} | fields]
    )
  end

  @doc "An unobserved map over the same cells as a planning grid (options as `new/3`)."
  @spec like(Grid.t(), keyword()) :: t()
  def like(%Grid{} = grid, opts \\ []),
    do: new(grid.width, grid.height, [resolution: grid.resolution, origin: grid.origin] ++ opts)

  @doc "Integrates one scan taken from `sensor_pose` (`{x, y, θ}` in the world)."
  @spec update(t(), map(), {number(), number(), number()}) :: t()
  def update(%__MODULE__{} = map, scan, {x, y, _th} = sensor_pose) do
    range_max = scan.range_max
    fade = fn d -> max(0.0, 1.0 - map.fade * d / range_max) end

    reading =
      scan
      |> Ray.beams(sensor_pose)
      |> Enum.reduce(%{}, fn {{px, py} = point, hit?}, reading ->
        {free, [last]} = Enum.split(Ray.cells(map.origin, map.resolution, {x, y}, point), -1)

        reading =
          Enum.reduce(free, reading, fn cell, reading ->
            {cx, cy} = centre(map, cell)
            d = :math.sqrt((cx - x) ** 2 + (cy - y) ** 2)
            contribute(map, reading, cell, map.k_empty * fade.(d), 0.0)
          end)

        if hit? do
          r = :math.sqrt((px - x) ** 2 + (py - y) ** 2)
          contribute(map, reading, last, 0.0, map.k_occupied * fade.(r))
        else
          contribute(map, reading, last, map.k_empty * fade.(range_max), 0.0)
        end
      end)

    cells =
      Enum.reduce(reading, map.cells, fn {index, {e, o}}, cells ->
        {e0, o0} = Map.get(cells, index, {0.0, 0.0})
        Map.put(cells, index, {union(e0, e), union(o0, o)})
      end)

    %{map | cells: cells}
  end

  defp contribute(%{width: w, height: h}, reading, {c, r}, e, o)
       when c >= 0 and r >= 0 and c < w and r < h do
    Map.update(reading, r * w + c, {e, o}, fn {e0, o0} -> {max(e0, e), max(o0, o)} end)
  end

  defp contribute(_map, reading, _cell, _e, _o), do: reading

  defp union(a, b), do: a + b - a * b

  defp centre(%{origin: {ox, oy}, resolution: res}, {c, r}),
    do: {ox + (c + 0.5) * res, oy + (r + 0.5) * res}

  @doc "The degrees `{empty, occupied}` of a cell (`{0, 0}` if unobserved or outside)."
  @spec degrees(t(), Grid.cell()) :: {float(), float()}
  def degrees(%__MODULE__{width: w, height: h, cells: cells}, {c, r})
      when c >= 0 and r >= 0 and c < w and r < h,
      do: Map.get(cells, r * w + c, {0.0, 0.0})

  def degrees(_map, _cell), do: {0.0, 0.0}

  @doc "How much a cell is an obstacle: `occupied ∧ ¬empty`."
  @spec occupied(t(), Grid.cell()) :: float()
  def occupied(map, cell) do
    {e, o} = degrees(map, cell)
    min(o, 1.0 - e)
  end

  @doc "How ambiguous a cell is: seen both empty and occupied, `empty ∧ occupied`."
  @spec ambiguous(t(), Grid.cell()) :: float()
  def ambiguous(map, cell) do
    {e, o} = degrees(map, cell)
    min(e, o)
  end

  @doc "How little is known of a cell: `¬empty ∧ ¬occupied` (1 if never seen)."
  @spec indeterminate(t(), Grid.cell()) :: float()
  def indeterminate(map, cell) do
    {e, o} = degrees(map, cell)
    min(1.0 - e, 1.0 - o)
  end

  @doc """
  A planning grid: a cell is blocked when its occupied-ness
  (`occupied ∧ ¬empty`) is at least `threshold` (default 0.5). Cells
  never observed are passable unless option `unknown: :blocked`.
  """
  @spec to_grid(t(), float(), keyword()) :: Grid.t()
  def to_grid(%__MODULE__{} = map, threshold \\ 0.5, opts \\ []) do
    unknown = if Keyword.get(opts, :unknown, :free) == :blocked, do: 1, else: 0

    observed =
      for {index, {e, o}} <- map.cells,
          do: {index, if(min(o, 1.0 - e) >= threshold, do: 1, else: 0)}

    cells = Sparse.to_binary(observed, map.width * map.height, unknown)
    Grid.new(map.width, map.height, cells: cells, resolution: map.resolution, origin: map.origin)
  end
end
