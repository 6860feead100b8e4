defmodule ThinkingCap.Navigation.Maps.LogOdds do
  @moduledoc """
  A log-odds occupancy grid built from range scans (Moravec & Elfes;
  Thrun, Burgard & Fox ch. 9), on the same cell layout as a planning
  `ThinkingCap.Navigation.Grid` (row-major from the bottom, `origin` the
  lower-left corner, `resolution` m per cell).

  Each cell holds `l = log(p / (1 − p))`, 0 (p = 0.5) until observed.
  `update/3` casts every beam of a scan from the sensor's pose through the
  grid (Amanatides & Woo's traversal) and applies the inverse sensor model:
  the cells a beam crosses before its end get `l_free`, the cell of its end
  `l_occ` (a reading at `range_max` is no echo: free space only); a cell
  seen by several beams of one scan is updated once, occupied winning over
  free. Values are clamped to `[l_min, l_max]` so that the map can change
  its mind when the world changes.

  Scans are laser scans in the sensor frame:
  `%{ranges: [m], angle_min: rad, angle_increment: rad, range_max: m}`
  (`range_min` optional, readings below it are dropped), as
  `ThinkingCap.Sim` publishes them; the sensor pose is `{x, y, θ}` in the
  world (the robot's pose composed with the sensor's mount).

  Only observed cells are stored (a map from cell index to log-odds), so a
  large, mostly unexplored grid costs nothing until it is explored.
  """

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Maps.Ray

  @enforce_keys [:width, :height]
  defstruct [
    :width,
    :height,
    resolution: 0.05,
    origin: {0.0, 0.0},
    l_occ: 0.85,
    l_free: -0.4,
    l_min: -2.0,
    l_max: 3.5,
    cells: %{}
  ]

  @type t :: %__MODULE__{
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float()},
          l_occ: float(),
          l_free: float(),
          l_min: float(),
          l_max: float(),
          cells: %{non_neg_integer() => float()}
        }
  @type scan :: %{
          required(:ranges) => [number()],
          required(:angle_min) => number(),
          required(:angle_increment) => number(),
          required(:range_max) => number(),
          optional(atom()) => term()
        }

  @doc """
  An unobserved `width` × `height` map. Options: `resolution` (default
  0.05), `origin` (default `{0, 0}`), and the model's `l_occ` (0.85),
  `l_free` (−0.4), `l_min` (−2.0), `l_max` (3.5).
  """
  @spec new(pos_integer(), pos_integer(), keyword()) :: t()
  def new(width, height, opts \\ []) do
    fields = Keyword.take(opts, [:origin, :l_occ, :l_free, :l_min, :l_max])

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
  @spec update(t(), scan(), {number(), number(), number()}) :: t()
  def update(%__MODULE__{} = map, scan, {x, y, _th} = sensor_pose) do
    seen =
      scan
      |> Ray.beams(sensor_pose)
      |> Enum.reduce(%{}, fn {point, hit?}, seen ->
        cells = Ray.cells(map.origin, map.resolution, {x, y}, point)
        {free, last} = Enum.split(cells, -1)
        seen = Enum.reduce(free, seen, &mark(map, &2, &1, :free))
        if hit?, do: mark(map, seen, hd(last), :occupied), else: mark(map, seen, hd(last), :free)
      end)

    cells =
      Enum.reduce(seen, map.cells, fn {index, kind}, cells ->
        delta = if kind == :occupied, do: map.l_occ, else: map.l_free
        l = Map.get(cells, index, 0.0) + delta
        Map.put(cells, index, l |> max(map.l_min) |> min(map.l_max))
      end)

    %{map | cells: cells}
  end

  defp mark(%{width: w, height: h}, seen, {c, r}, kind)
       when c >= 0 and r >= 0 and c < w and r < h do
    index = r * w + c

    case kind do
      :occupied -> Map.put(seen, index, :occupied)
      :free -> Map.put_new(seen, index, :free)
    end
  end

  defp mark(_map, seen, _cell, _kind), do: seen

  @doc "The log-odds of a cell (0.0 if unobserved or outside)."
  @spec log_odds(t(), Grid.cell()) :: float()
  def log_odds(%__MODULE__{width: w, height: h, cells: cells}, {c, r})
      when c >= 0 and r >= 0 and c < w and r < h,
      do: Map.get(cells, r * w + c, 0.0)

  def log_odds(_map, _cell), do: 0.0

  @doc "The probability that a cell is occupied (0.5 if unobserved)."
  @spec probability(t(), Grid.cell()) :: float()
  def probability(map, cell), do: 1.0 - 1.0 / (1.0 + :math.exp(log_odds(map, cell)))

  @doc "Whether a cell has been observed by any scan."
  @spec observed?(t(), Grid.cell()) :: boolean()
  def observed?(%__MODULE__{width: w, height: h, cells: cells}, {c, r})
      when c >= 0 and r >= 0 and c < w and r < h,
      do: Map.has_key?(cells, r * w + c)

  def observed?(_map, _cell), do: false

  @doc """
  A planning grid: a cell is blocked when its probability of being
  occupied is at least `threshold` (default 0.65). Unobserved cells have
  probability 0.5, so they are blocked only by a threshold of 0.5 or less,
  unless option `unknown: :blocked | :free` decides for them.
  """
  @spec to_grid(t(), float(), keyword()) :: Grid.t()
  def to_grid(%__MODULE__{} = map, threshold \\ 0.65, opts \\ []) do
    l_threshold = :math.log(threshold / (1.0 - threshold))

    unknown =
      case Keyword.get(opts, :unknown) do
        :blocked -> 1
        :free -> 0
        nil -> if 0.0 >= l_threshold, do: 1, else: 0
      end

    observed = for {index, l} <- map.cells, do: {index, if(l >= l_threshold, do: 1, else: 0)}

    cells =
      ThinkingCap.Navigation.Maps.Sparse.to_binary(observed, map.width * map.height, unknown)

    Grid.new(map.width, map.height, cells: cells, resolution: map.resolution, origin: map.origin)
  end
end
