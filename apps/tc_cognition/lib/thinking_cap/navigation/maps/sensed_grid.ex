defmodule ThinkingCap.Navigation.Maps.SensedGrid do
  @moduledoc """
  The fuzzy grid map a running robot builds from its range sensors: the
  model of `ThinkingCap.Navigation.Maps.FuzzyGrid` (every cell carries a
  degree of **empty** `E` and of **occupied** `O`, gathered from readings
  along their beams; `O ∧ ¬E` is what the planner avoids), kept in a NIF
  (`c_src/tc_grid.c`) so that a laser scan costs well under a millisecond
  on a map of millions of cells, plus **fading**: what is now seen empty
  fades out of the occupied degree, and what is seen occupied out of the
  empty one,

      O' = O · (1 − λe·e)     E' = E · (1 − λo·o)
      E'' = E' ∨ e            O'' = O' ∨ o          (a ∨ b = a + b − a·b)

  so that a moved pallet, a door shut or a person who walked away leaves
  the map after a few scans, while evidence that keeps agreeing builds up
  towards 1. An echo counts more than a beam passing by (`λo` 1, `λe`
  0.2 by default): a wall seen at a grazing angle from poses a centimetre
  apart is hit by some beams and crossed by others, and must stay a wall.
  An echo marks the cell just beyond the surface it came from (0.3 cell
  further along its beam), so that a surface lying on a cell boundary
  always lands on its own side.

  A reading contributes along its beam: to the cells before its end an
  empty degree `k_empty · fade(d)` (up to `margin` short of an echo, so
  that a wall seen at a grazing angle is not emptied by its own beams),
  and to the cell of the echo an occupied degree `k_occupied · fade(r)`,
  with `fade(d) = 1 − fade · d / range_max`. Within one reading (a laser
  scan, a sonar cone) a cell takes the largest contribution (`max`).

  Laser beams are taken as they come (defaults `k_empty` 0.3,
  `k_occupied` 0.5) up to `range` (default 6 m): far beyond it, a beam
  that grazes a wall lands a hand's width off it for a heading a degree
  off, so it says only that the space before is free. A sonar reading is a cone: its echo may come from
  anywhere across the cone and a specular wall may send it on a longer
  path, so it is spread over rays across the cone with weaker degrees
  (defaults `k_empty` 0.12, `k_occupied` 0.3), and its empty evidence is
  trusted only up to `sonar_trust` metres (default 3).

  The value is mutable (a NIF resource): `add_*` functions change it in
  place and return it. `export/1` and `import/2` carry it to a standby.
  """

  alias ThinkingCap.Navigation.Core.GridNif
  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}

  @enforce_keys [:ref, :width, :height]
  defstruct [
    :ref,
    :width,
    :height,
    resolution: 0.05,
    origin: {0.0, 0.0},
    fade: 0.5,
    lambda: {0.2, 1.0},
    margin: nil,
    known: 0.25,
    laser: %{k_empty: 0.3, k_occupied: 0.5, range: 6.0},
    sonar: %{k_empty: 0.12, k_occupied: 0.3, trust: 3.0, ray_spacing: 0.05}
  ]

  @type t :: %__MODULE__{
          ref: reference(),
          width: pos_integer(),
          height: pos_integer(),
          resolution: float(),
          origin: {float(), float()},
          fade: float(),
          lambda: {float(), float()},
          margin: float(),
          known: float(),
          laser: map(),
          sonar: map()
        }

  @type pose :: {number(), number(), number()}

  @doc """
  An unobserved map of `width` × `height` cells. Options: `resolution`
  (default 0.05 m), `origin` (world position of the lower-left corner,
  default `{0, 0}`), `fade`, `lambda` (the fading `{λe, λo}`, default
  `{0.2, 1.0}`), `margin`
  (default 1.5 cells), `known` (a cell whose degrees are both below this
  is unknown, default 0.25: a beam grazing a cell once does not make it
  known), `laser` and `sonar` (maps of the degrees
  above, merged with the defaults).
  """
  @spec new(pos_integer(), pos_integer(), keyword()) :: t()
  def new(width, height, opts \\ []) do
    res = Keyword.get(opts, :resolution, 0.05) * 1.0
    {ox, oy} = Keyword.get(opts, :origin, {0.0, 0.0})
    ref = GridNif.fmap_new(width, height, res, ox * 1.0, oy * 1.0)
    defaults = %__MODULE__{ref: ref, width: width, height: height}

    %{
      defaults
      | resolution: res,
        origin: {ox * 1.0, oy * 1.0},
        fade: Keyword.get(opts, :fade, defaults.fade) * 1.0,
        lambda: lambdas(Keyword.get(opts, :lambda, defaults.lambda)),
        margin: Keyword.get(opts, :margin, 1.5 * res) * 1.0,
        known: Keyword.get(opts, :known, defaults.known) * 1.0,
        laser: Map.merge(defaults.laser, Map.new(Keyword.get(opts, :laser, []))),
        sonar: Map.merge(defaults.sonar, Map.new(Keyword.get(opts, :sonar, [])))
    }
  end

  defp lambdas({e, o}), do: {e * 1.0, o * 1.0}

  @doc """
  A map over the cells of an occupancy grid, seeded with it: occupied
  cells start with `O = strength`, free ones with `E = strength`, unknown
  ones unobserved (default strength 0.7: an a priori map is believed,
  and corrected by what is sensed). Options as `new/3`.
  """
  @spec seeded(OccupancyGrid.t(), float(), keyword()) :: t()
  def seeded(%OccupancyGrid{} = prior, strength \\ 0.7, opts \\ []) do
    map =
      new(
        prior.width,
        prior.height,
        [resolution: prior.resolution, origin: prior.origin] ++ opts
      )

    :ok = GridNif.fmap_seed(map.ref, prior.data, strength * 1.0)
    map
  end

  @doc """
  Integrates a laser scan (`%{ranges:, angle_min:, angle_increment:,
  range_max:, range_min:}`, angles relative to the sensor) taken by a
  sensor at `sensor_pose` in the world. Returns the map (changed in place).
  """
  @spec add_laser(t(), map(), pose()) :: t()
  def add_laser(%__MODULE__{} = map, scan, {x, y, th}) do
    %{k_empty: k_e, k_occupied: k_o, range: usable} = map.laser
    range_min = Map.get(scan, :range_min, 0.0)
    range_max = min(scan.range_max, usable)

    rays =
      scan.ranges
      |> Enum.with_index()
      |> Enum.reduce([], fn {r, i}, acc ->
        if is_number(r) and r >= range_min do
          a = th + scan.angle_min + i * scan.angle_increment
          # beyond the usable range: free up to it, no echo
          {r, k_o} = if r < range_max, do: {r, k_o}, else: {range_max, 0.0}
          [<<a::float-native, r::float-native, k_e::float-native, k_o::float-native>> | acc]
        else
          acc
        end
      end)

    integrate(map, {x, y}, rays, range_max)
  end

  @doc """
  Integrates many laser scans of one sensor at once, in order, as
  `add_laser/3` would one by one: `poses` the sensor's pose in the world
  for each scan (native doubles `{x, y, θ}`), `ranges` `beams` 32-bit
  native floats per scan (a range below `range_min` is no reading), and
  `scan` the sensor's `angle_min`, `angle_increment`, `range_min` and
  `range_max`. For drawing a map again from kept scans.
  """
  @spec replay_lasers(t(), binary(), binary(), pos_integer(), map()) :: t()
  def replay_lasers(%__MODULE__{} = map, poses, ranges, beams, scan) do
    %{k_empty: k_e, k_occupied: k_o, range: usable} = map.laser
    range_max = min(scan.range_max, usable) * 1.0

    meta =
      {scan.angle_min * 1.0, scan.angle_increment * 1.0, Map.get(scan, :range_min, 0.0) * 1.0,
       range_max}

    _changed =
      GridNif.fmap_replay(
        map.ref,
        poses,
        ranges,
        beams,
        meta,
        {k_e * 1.0, k_o * 1.0},
        map.fade,
        map.lambda,
        map.margin
      )

    map
  end

  @doc """
  Integrates a sonar ring reading (`%{ranges:, headings:, range_max:}`,
  one range per transducer, headings in the robot frame) of a ring
  described by `ring` (`%{pose: {x, y, θ}, ring_radius: r, fov: f}` as in
  the RDF) on a robot at `robot_pose` in the world.
  """
  @spec add_sonar(t(), map(), pose(), map()) :: t()
  def add_sonar(%__MODULE__{} = map, reading, {x, y, th}, ring) do
    %{k_empty: k_e, k_occupied: k_o, trust: trust, ray_spacing: spacing} = map.sonar
    {px, py, _} = Map.get(ring, :pose, {0.0, 0.0, 0.0})
    rr = Map.get(ring, :ring_radius, 0.0)
    fov = Map.get(ring, :fov, 0.0)
    range_min = Map.get(reading, :range_min, 0.0)
    range_max = min(reading.range_max, trust)
    {c, s} = {:math.cos(th), :math.sin(th)}

    reading.ranges
    |> Enum.zip(reading.headings)
    |> Enum.reduce(map, fn {r, h}, map ->
      if is_number(r) and r >= range_min do
        # the transducer on the ring, in the world
        {tx, ty} = {px + rr * :math.cos(h), py + rr * :math.sin(h)}
        origin = {x + c * tx - s * ty, y + s * tx + c * ty}
        # an echo beyond the trusted range says only: free up to there
        {r, echo} = if r < range_max, do: {r, k_o}, else: {range_max, 0.0}
        # rays across the cone, at most `spacing` apart (and a cell apart at the echo)
        n = min(64, max(ceil(fov / spacing), ceil(fov * r / map.resolution)) + 1)

        offsets =
          if fov == 0, do: [0.0], else: for(j <- 0..(n - 1), do: -fov / 2 + j * fov / (n - 1))

        rays =
          for o <- offsets,
              do:
                <<th + h + o::float-native, r::float-native, k_e::float-native,
                  echo::float-native>>

        integrate(map, origin, rays, range_max + 1.0e-6)
      else
        map
      end
    end)
  end

  @doc """
  Marks the ground under the robot as empty: the robot stands there, so
  nothing else does. `discs` are `{x, y, r}` in the robot frame (as
  `ThinkingCap.Robot.Description.circles/1` gives them), each emptied
  over 80 % of its radius with degree `k_empty` (default 0.3), from 24
  rays out of its centre. A robot started in unknown space thus stands
  in known free space from its first reading on.
  """
  @spec add_footprint(t(), pose(), [{number(), number(), number()}], float()) :: t()
  def add_footprint(%__MODULE__{} = map, {x, y, th}, discs, k_empty \\ 0.3) do
    {c, s} = {:math.cos(th), :math.sin(th)}

    Enum.reduce(discs, map, fn {dx, dy, r}, map ->
      reach = 0.8 * r
      centre = {x + c * dx - s * dy, y + s * dx + c * dy}

      rays =
        for i <- 0..23,
            do:
              <<i * :math.pi() / 12::float-native, reach::float-native, k_empty::float-native,
                0.0::float-native>>

      integrate(map, centre, rays, reach + 1.0e-6)
    end)
  end

  defp integrate(map, {x, y}, rays, range_max) do
    _changed =
      GridNif.fmap_integrate(
        map.ref,
        x * 1.0,
        y * 1.0,
        IO.iodata_to_binary(rays),
        range_max * 1.0,
        map.fade,
        map.lambda,
        map.margin
      )

    map
  end

  @doc "The degrees `{empty, occupied}` of a cell (`{0, 0}` if unobserved or outside)."
  @spec degrees(t(), Grid.cell()) :: {float(), float()}
  def degrees(%__MODULE__{ref: ref}, {c, r}), do: GridNif.fmap_degrees(ref, c, r)

  @doc "How much a cell is an obstacle: `occupied ∧ ¬empty`."
  @spec occupied(t(), Grid.cell()) :: float()
  def occupied(map, cell) do
    {e, o} = degrees(map, cell)
    min(o, 1.0 - e)
  end

  @doc """
  The cells observed so far, `{col_min, row_min, col_max, row_max}`, or
  nil before the first reading.
  """
  @spec observed_box(t()) :: {integer(), integer(), integer(), integer()} | nil
  def observed_box(%__MODULE__{ref: ref}), do: GridNif.fmap_bbox(ref)

  @doc """
  The map as an occupancy grid: each cell `round(100 · (O ∧ ¬E))`, or −1
  where both degrees are below `known`. Option `crop: true` (default)
  keeps only the observed cells plus `pad` cells (default 10) around them,
  within the map; `crop: false` the whole map. `version` and `stamp` are
  set as given.
  """
  @spec occupancy(t(), keyword()) :: OccupancyGrid.t()
  def occupancy(%__MODULE__{} = map, opts \\ []) do
    pad = Keyword.get(opts, :pad, 10)

    {c0, r0, c1, r1} =
      case Keyword.get(opts, :crop, true) && observed_box(map) do
        {a, b, c, d} ->
          {max(a - pad, 0), max(b - pad, 0), min(c + pad, map.width - 1),
           min(d + pad, map.height - 1)}

        _ ->
          {0, 0, map.width - 1, map.height - 1}
      end

    {w, h} = {c1 - c0 + 1, r1 - r0 + 1}
    {ox, oy} = map.origin

    %OccupancyGrid{
      width: w,
      height: h,
      data: GridNif.fmap_occupancy(map.ref, c0, r0, w, h, map.known),
      resolution: map.resolution,
      origin: {ox + c0 * map.resolution, oy + r0 * map.resolution},
      version: Keyword.get(opts, :version, 0),
      stamp: Keyword.get(opts, :stamp)
    }
  end

  @doc "The degrees of every cell as a binary (for a standby: `import/2`)."
  @spec export(t()) :: binary()
  def export(%__MODULE__{ref: ref}), do: GridNif.fmap_export(ref)

  @doc "Sets every cell's degrees from `export/1` of a map of the same size."
  @spec import(t(), binary()) :: :ok | {:error, String.t()}
  def import(%__MODULE__{ref: ref, width: w, height: h}, binary) when is_binary(binary) do
    if byte_size(binary) == 4 * w * h,
      do: GridNif.fmap_import(ref, binary),
      else: {:error, "the exported map holds #{byte_size(binary)} bytes, not #{4 * w * h}"}
  end
end
