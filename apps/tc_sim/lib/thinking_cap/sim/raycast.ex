defmodule ThinkingCap.Sim.Raycast do
  # rays x (1 + max_bounces) above which a call runs on a dirty CPU
  # scheduler: DIRTY_RAY_BUDGET in c_src/tc_raycast.c
  @dirty_budget 4000
  # a scan's rays with their bounces: the packed header holds 32 bits
  @max_budget 0xFFFFFFFF

  @moduledoc """
  Ray casting for the simulator: a NIF (`c_src/tc_raycast.c`, built by the
  app's own `Mix.Tasks.Compile.TcRaycast` into `priv/lib/tc_raycast.so`).

  A *world* holds static geometry — line segments (walls, doors) and an
  optional occupancy grid — and dynamic circular bodies (the robots). It is
  a NIF resource shared by any number of processes: casts and clearance
  queries take its read lock, `set_segment/3` and `set_bodies/2` its write
  lock, so processes cast concurrently. Units are metres and radians.

  ## Geometry

    * Segments are indexed by a uniform grid of buckets (0.5–1 m, from the
      extent and the segment count). A disabled segment is not hit.
    * The occupancy grid (`ThinkingCap.Config.RosMap` or a plain map with
      the same fields) has one signed byte per cell, row-major from the
      bottom row; cells with a value ≥ 50 are obstacles, unknown (−1) is
      free, and everything outside the grid is free. `origin` is the world
      pose of the lower-left corner of cell (0, 0); the grid may be rotated
      by its yaw. An exact Euclidean distance transform computed by `new/1`
      lets rays jump across free space; near obstacles they step cell by
      cell, and the hit is the exact entry point of the first obstacle cell
      along the ray. The jumps are kept per cell and, 64 times smaller, per
      8 × 8 tile (the least of its cells'), so that a ray crossing open
      space reads the small map, which stays in the caches of a large map.
    * Bodies are circles; a body's list index is its id, and a caller
      excludes its own body (`exclude`, −1 for none). `set_bodies/2`
      indexes them by centre in a uniform grid of buckets (about one body
      per bucket), so a scan, a cast or a clearance query looks only at the
      bodies within its reach: its cost depends on how dense the bodies
      are, not on how many there are.

  ## Reflection model (sonar)

  When a ray hits a surface, α is the angle between the reversed ray and the
  surface normal. If α ≤ `critical_angle` the echo returns and the reading
  is the total path length travelled (the direct distance without bounces).
  Otherwise the surface reflects specularly: the ray goes on from the hit
  point with direction d − 2(d·n)n and the remaining range. After more than
  `max_bounces` reflections, or when the range runs out, there is no echo
  and the reading is the maximum range (hit `:none`). Normals are exact for
  segments and bodies; for grid cells the normal points away from the
  occupied cells of the 5×5 neighbourhood of the hit cell, or is the normal
  of the cell face the ray crossed when that estimate is degenerate or does
  not face the ray. A critical angle ≥ π/2 means every hit echoes (a laser).

  ## Scheduling

  `new/1` (which computes the distance transform) always runs on a dirty
  CPU scheduler. `scan/5` and `cast_rays/3` run on the calling scheduler
  unless the call's ray budget — rays × (1 + max_bounces), summed over the
  groups (see `ray_budget/1`) — exceeds #{@dirty_budget}; then the NIF
  reschedules itself onto a dirty CPU scheduler (`enif_schedule_nif`),
  invisibly to the caller.

  ## Performance

  `mix tc.bench raycast` (`bench/raycast_bench.exs`) measures `scan/5` in
  the 30 m × 50 m warehouse map (3 cm cells) with 100 robots, each with a
  180-beam laser (one group per beam) and 16 three-ray sonars with
  reflections and crosstalk (196 groups, 228 rays per scan): about 40 µs
  per scan, 5.8 M rays/s on one core and 11 M rays/s on two (AMD EPYC,
  2 cores).
  """

  @on_load :load_nif

  @typedoc "A world (a NIF resource)."
  @type world :: reference()

  @typedoc "A segment: its two end points, metres."
  @type segment :: {{number(), number()}, {number(), number()}}

  @typedoc "A ray: origin, direction angle and maximum range."
  @type ray :: {number(), number(), number(), number()}

  @typedoc "What a ray returned: the reading, what it hit, the bounces before the echo and the id of the segment or body hit (−1 otherwise)."
  @type result :: %{
          range: float(),
          hit: :none | :grid | :segment | :body,
          bounces: non_neg_integer(),
          id: integer()
        }

  @typedoc "A sensor group for `pack_groups/1`; see there for the keys and defaults."
  @type group :: %{optional(atom()) => number()}

  @max_bounces 1000
  @half_pi :math.pi() / 2
  @two_pi 2 * :math.pi()

  @group_defaults %{
    x: 0.0,
    y: 0.0,
    heading: 0.0,
    fov: 0.0,
    rays: 1,
    min_range: 0.0,
    max_bounces: 0,
    critical_angle: @half_pi,
    ring: -1,
    noise_std: 0.0,
    noise_prop: 0.0,
    dropout: 0.0,
    spike: 0.0,
    spike_magnitude: 0.0,
    bias: 0.0
  }

  # a number that converts to a float64
  defguardp real(x) when is_float(x) or (is_integer(x) and abs(x) < 1.0e300)
  defp real?(x), do: real(x)

  defp load_nif do
    path = :filename.join(:code.priv_dir(:tc_sim), ~c"lib/tc_raycast")
    :erlang.load_nif(path, 0)
  end

  @doc """
  Builds a world.

  Options:

    * `:segments` — `[{{x1, y1}, {x2, y2}}]`, the list index is the segment
      id (default `[]`);
    * `:grid` — `nil` (default), a `ThinkingCap.Config.RosMap` or a map
      `%{width:, height:, resolution:, origin: {x, y, yaw}, data:}`.

  Returns `{:error, message}` naming what is wrong for bad input.
  """
  @spec new(keyword()) :: {:ok, world()} | {:error, String.t()}
  def new(opts) when is_list(opts) do
    with :ok <- check_keys(opts),
         {:ok, segments} <- pack_segments(Keyword.get(opts, :segments, [])),
         {:ok, grid} <- grid_args(Keyword.get(opts, :grid)) do
      nif_new(segments, grid)
    end
  end

  def new(opts), do: {:error, "options: expected a keyword list, got #{inspect(opts)}"}

  @doc """
  Enables or disables segment `id` (a door opening or closing). A disabled
  segment is not hit and does not count for `clearance/5`. Raises
  `ArgumentError` for an unknown id.
  """
  @spec set_segment(world(), non_neg_integer(), boolean()) :: :ok
  def set_segment(_world, _id, _enabled), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  Replaces the dynamic bodies by `bodies`, `[{x, y, radius}]`; the list
  index is the body id.
  """
  @spec set_bodies(world(), [{number(), number(), number()}]) :: :ok
  def set_bodies(_world, _bodies), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  Replaces the dynamic bodies by bodies `0..n-1` given as `records`, a
  binary of four native float64 per body: `id, x, y, radius` (as
  `body_record/4` writes them, in any order). A body no record names is
  parked far away with radius 0 (it is never hit). Cheaper than
  `set_bodies/2` for many bodies: nothing is decoded term by term.
  Raises `ArgumentError` for an id outside `0..n-1`, a coordinate that is
  not finite or a negative radius.
  """
  @spec set_bodies_packed(world(), non_neg_integer(), binary()) :: :ok
  def set_bodies_packed(_world, _n, _records), do: :erlang.nif_error(:nif_not_loaded)

  @doc "One body's record for `set_bodies_packed/3`."
  @spec body_record(non_neg_integer(), number(), number(), number()) :: binary()
  def body_record(id, x, y, radius),
    do:
      <<id * 1.0::float-native-64, x * 1.0::float-native-64, y * 1.0::float-native-64,
        radius * 1.0::float-native-64>>

  @doc """
  The discs that ran into each other in one step of simultaneous moves.
  `moves` is a binary of six native float64 per disc (`move_record/6`):
  `id`, where it stood `x0, y0`, where it moved to `x1, y1`, and its
  radius. Two moves clash when the discs end overlapping and nearer than
  they were (two discs that already overlap may move apart). Returns the
  ids of the moves in a clash, ascending, each once. A grid of buckets as
  wide as the largest contact distance keeps it linear in the number of
  moves. Raises `ArgumentError` for a malformed binary, a value that is
  not finite, a negative radius or an id that is not a whole number ≥ 0.
  """
  @spec contacts(binary()) :: [non_neg_integer()]
  def contacts(_moves), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  One step of walkers among robots (`ThinkingCap.Sim.Core.Walkers`, in
  C). `robots` holds three native float64 per robot (`x, y, radius`),
  `walkers` six per walker in the order they step (`x, y, radius`, the
  target's `x, y`, `speed`). Each walker in turn goes straight towards
  its target at its speed: onto it when it is within `speed * dt`
  (arrived: no check), else one step if the new place keeps more than
  `gap` from every robot and every other walker as they stand by then,
  else it waits. Returns three native float64 per walker: where it
  stands and 0.0 (waited), 1.0 (stepped) or 2.0 (arrived). Raises
  `ArgumentError` for a malformed binary, a value that is not finite, a
  negative radius, speed, `dt` or `gap`.
  """
  @spec walkers_step(binary(), binary(), float(), float()) :: binary()
  def walkers_step(_robots, _walkers, _dt, _gap), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  The box `{min_x, min_y, max_x, max_y}` round the centres of body
  records (`body_record/4`, packed), `nil` for none.
  """
  @spec records_box(binary()) :: {float(), float(), float(), float()} | nil
  def records_box(_records), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  The body records (`body_record/4`, packed) whose disc reaches into the
  box from `{min_x, min_y}` to `{max_x, max_y}`, in their order.
  """
  @spec records_within(binary(), float(), float(), float(), float()) :: binary()
  def records_within(_records, _min_x, _min_y, _max_x, _max_y),
    do: :erlang.nif_error(:nif_not_loaded)

  @doc "One disc's move for `contacts/1`."
  @spec move_record(non_neg_integer(), number(), number(), number(), number(), number()) ::
          binary()
  def move_record(id, x0, y0, x1, y1, radius),
    do:
      <<id * 1.0::float-native-64, x0 * 1.0::float-native-64, y0 * 1.0::float-native-64,
        x1 * 1.0::float-native-64, y1 * 1.0::float-native-64, radius * 1.0::float-native-64>>

  @doc """
  Casts `rays`, `[{x, y, angle, max_range}]`, and returns one result per
  ray, in order.

  Options: `exclude:` a body id not to see (default −1), `max_bounces:`
  (default 0) and `critical_angle:` (default π/2: every hit echoes), see
  the reflection model in the module documentation. `range` is `max_range`
  when there is no echo (`hit: :none`); `bounces` counts the reflections
  before the echo (or made before giving up).
  """
  @spec cast_rays(world(), [ray()], keyword()) :: [result()]
  def cast_rays(world, rays, opts \\ []) do
    exclude = Keyword.get(opts, :exclude, -1)
    max_bounces = Keyword.get(opts, :max_bounces, 0)
    critical = Keyword.get(opts, :critical_angle, @half_pi)

    unless is_integer(exclude), do: raise(ArgumentError, "exclude: expected an integer")

    unless is_integer(max_bounces) and max_bounces in 0..@max_bounces,
      do: raise(ArgumentError, "max_bounces: expected an integer from 0 to #{@max_bounces}")

    unless real?(critical), do: raise(ArgumentError, "critical_angle: expected a number")

    nif_cast_rays(world, rays, exclude, max_bounces, cos_critical(critical))
  end

  @doc """
  One sensor step of a robot at `pose` `{x, y, theta}`: casts the rays of
  every group of `groups` (a binary from `pack_groups/1`, computed once per
  robot) and returns one little-endian float64 per group, in order: the
  group's reading after crosstalk, noise and faults. Body `exclude` (the
  robot itself, −1 for none) is not seen.

  A group's reading before noise is the minimum over its rays' echo ranges
  (its `max_range` if none echoes).

  **Crosstalk**: among the groups with the same `ring` ≥ 0, the echo of a
  ray that bounced at least once comes back from its last (diffuse) hit
  point P with path length L; every *other* group j of the ring whose cone
  (its heading ± fov/2 seen from its own position) contains P receives a
  reading (L + |P − pos_j|)/2, and j's reading is the minimum of its own
  echoes and such arrivals. The return leg P → j is not checked for line of
  sight.

  **Noise and faults**: for a reading r below `max_range` (an echo), add
  `bias`, then Gaussian noise with σ = `noise_std` + `noise_prop`·r (r
  before bias), then clamp to [`min_range`, `max_range`]. Then one uniform
  draw u decides the fault: u < `dropout` turns an echo into `max_range`;
  `dropout` ≤ u < `dropout` + `spike` gives a spike — a uniform reading in
  [`min_range`, `max_range`] when `spike_magnitude` is 0, otherwise r +
  uniform(−m, m) clamped to the range. Echo-less readings get no noise and
  no dropout, but may spike. So the frequencies are exactly `dropout` (of
  echoes) and `spike`.

  Deterministic: the noise and faults draw from one splitmix64 stream
  seeded from `seed` (< 2⁶⁴), in group order and only as needed (a
  Gaussian by the ziggurat method for a noisy echo; a uniform for the
  fault of a group with faults; another for a spike's value), so the
  same inputs give the same bytes.
  """
  @spec scan(world(), {number(), number(), number()}, binary(), integer(), non_neg_integer()) ::
          binary()
  def scan(_world, _pose, _groups, _exclude, _seed), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  `scan/5` with the readings as a list of floats (what sensor payloads
  carry), built in C: cheaper than decoding the binary.
  """
  @spec scan_list(world(), {number(), number(), number()}, binary(), integer(), non_neg_integer()) ::
          [float()]
  def scan_list(_world, _pose, _groups, _exclude, _seed), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  The least of `count` readings of a `scan/5` binary from index `first`
  (0-based; `count` ≥ 1, all within the binary): no float is made for
  the others.
  """
  @spec ranges_min(binary(), non_neg_integer(), pos_integer()) :: float()
  def ranges_min(_readings, _first, _count), do: :erlang.nif_error(:nif_not_loaded)

  @doc """
  Packs sensor groups for `scan/5`. Each group is a map; missing keys take
  the defaults shown:

    * `x: 0.0, y: 0.0, heading: 0.0` — the sensor's pose in the robot frame;
    * `fov: 0.0` — cone width; `rays: 1` rays spread evenly across it, at
      offsets −fov/2 + (k + 0.5)·fov/n (one ray: the centre);
    * `max_range:` (required, > 0), `min_range: 0.0`;
    * `max_bounces: 0`, `critical_angle: π/2` (every hit echoes);
    * `ring: -1` — the crosstalk ring (an integer ≥ 0), −1 for none;
    * `noise_std: 0.0, noise_prop: 0.0, bias: 0.0`;
    * `dropout: 0.0, spike: 0.0` (probabilities; the two faults exclude
      each other, so when they add up to more than 1 a spike's probability
      is 1 − dropout), `spike_magnitude: 0.0`.

  Raises `ArgumentError` naming the group and key for bad values.
  """
  @spec pack_groups([group()]) :: binary()
  def pack_groups(groups) when is_list(groups) do
    {records, rays, _} =
      groups
      |> Enum.with_index()
      |> Enum.reduce({[], [], 0}, fn {group, i}, {records, rays, offset} ->
        g = group_params(group, i)
        n = g.rays

        record = [
          g.x,
          g.y,
          :math.cos(g.heading),
          :math.sin(g.heading),
          cos_half_fov(g.fov),
          n,
          offset,
          g.min_range,
          g.max_range,
          g.max_bounces,
          cos_critical(g.critical_angle),
          g.ring,
          g.noise_std,
          g.noise_prop,
          g.dropout,
          g.spike,
          g.spike_magnitude,
          g.bias,
          g.fov,
          sin_half_fov(g.fov)
        ]

        ray_dirs =
          for k <- 0..(n - 1) do
            a = g.heading - g.fov / 2 + (k + 0.5) * g.fov / n
            [:math.cos(a), :math.sin(a)]
          end

        {[record | records], [ray_dirs | rays], offset + n}
      end)

    doubles = Enum.reverse(records) ++ Enum.reverse(rays)
    nrays = rays |> Enum.map(&length/1) |> Enum.sum()

    budget =
      for [_, _, _, _, _, n, _, _, _, mb | _] <- records, reduce: 0 do
        acc -> acc + n * (1 + mb)
      end

    if budget > @max_budget,
      do:
        raise(ArgumentError, "groups: #{budget} rays with their bounces, at most #{@max_budget}")

    body = for d <- List.flatten(doubles), into: <<>>, do: <<d::float-native-64>>
    <<"TCG1", length(groups)::native-32, nrays::native-32, budget::native-32, body::binary>>
  end

  @doc """
  The ray budget of a packed groups binary: rays × (1 + max_bounces) summed
  over the groups, as `pack_groups/1` wrote it in the header. `scan/5` runs
  on a dirty CPU scheduler above #{@dirty_budget}, and refuses groups that
  do not add up to their header's budget.
  """
  @spec ray_budget(binary()) :: non_neg_integer()
  def ray_budget(<<"TCG1", _ng::native-32, _nrays::native-32, budget::native-32, _::binary>>),
    do: budget

  @doc """
  The distance from (`x`, `y`) to the nearest obstacle — an enabled segment,
  the nearest point of an obstacle grid cell, or the surface of a body other
  than `exclude` — capped at `max`. 0.0 inside an obstacle cell or a body.
  """
  @spec clearance(world(), number(), number(), integer(), number()) :: float()
  def clearance(_world, _x, _y, _exclude, _max), do: :erlang.nif_error(:nif_not_loaded)

  ## NIF entry points

  defp nif_new(_segments, _grid), do: :erlang.nif_error(:nif_not_loaded)

  defp nif_cast_rays(_world, _rays, _exclude, _max_bounces, _cos_critical),
    do: :erlang.nif_error(:nif_not_loaded)

  ## Validation and packing

  defp check_keys(opts) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "options: expected a keyword list, got #{inspect(opts)}"}

      (unknown = Keyword.keys(opts) -- [:segments, :grid]) != [] ->
        {:error, "options: unknown #{inspect(hd(unknown))} (expected :segments and/or :grid)"}

      true ->
        :ok
    end
  end

  defp pack_segments(segments) when is_list(segments) do
    segments
    |> Enum.with_index()
    |> Enum.reduce_while({:ok, []}, fn
      {{{x1, y1}, {x2, y2}}, _i}, {:ok, acc}
      when real(x1) and real(y1) and real(x2) and real(y2) ->
        {:cont,
         {:ok,
          [
            <<x1::float-native-64, y1::float-native-64, x2::float-native-64, y2::float-native-64>>
            | acc
          ]}}

      {other, i}, _ ->
        {:halt,
         {:error,
          "segment #{i}: expected {{x1, y1}, {x2, y2}} with numbers, got #{inspect(other)}"}}
    end)
    |> case do
      {:ok, parts} -> {:ok, parts |> Enum.reverse() |> IO.iodata_to_binary()}
      error -> error
    end
  end

  defp pack_segments(other),
    do: {:error, "segments: expected a list of {{x1, y1}, {x2, y2}}, got #{inspect(other)}"}

  defp grid_args(nil), do: {:ok, nil}

  defp grid_args(%{} = grid) do
    with {:ok, w} <- grid_field(grid, :width, &(is_integer(&1) and &1 > 0), "a positive integer"),
         {:ok, h} <-
           grid_field(grid, :height, &(is_integer(&1) and &1 > 0), "a positive integer"),
         {:ok, res} <-
           grid_field(grid, :resolution, &(real?(&1) and &1 > 0), "a positive number"),
         {:ok, {ox, oy, yaw}} <- grid_field(grid, :origin, &origin?/1, "{x, y, yaw} numbers"),
         {:ok, data} <- grid_field(grid, :data, &is_binary/1, "a binary") do
      if byte_size(data) == w * h do
        {:ok, {w, h, res / 1, ox / 1, oy / 1, yaw / 1, data}}
      else
        {:error,
         "grid: data has #{byte_size(data)} bytes, expected width * height = #{w} * #{h} = #{w * h}"}
      end
    end
  end

  defp grid_args(other),
    do: {:error, "grid: expected nil or a map (ThinkingCap.Config.RosMap), got #{inspect(other)}"}

  defp grid_field(grid, key, valid?, expected) do
    case Map.fetch(grid, key) do
      {:ok, value} ->
        if valid?.(value),
          do: {:ok, value},
          else: {:error, "grid: #{key}: expected #{expected}, got #{inspect(value)}"}

      :error ->
        {:error, "grid: missing #{key}"}
    end
  end

  defp origin?({x, y, yaw}), do: real?(x) and real?(y) and real?(yaw)
  defp origin?(_), do: false

  defp group_params(group, i) when is_map(group) do
    unless Map.has_key?(group, :max_range),
      do: raise(ArgumentError, "group #{i}: missing :max_range")

    case Map.keys(group) -- [:max_range | Map.keys(@group_defaults)] do
      [] -> :ok
      [key | _] -> raise ArgumentError, "group #{i}: unknown key #{inspect(key)}"
    end

    g = Map.merge(@group_defaults, group)

    for {key, value} <- g, not real?(value) do
      raise ArgumentError, "group #{i}: #{key}: expected a number, got #{inspect(value)}"
    end

    check(g.max_range > 0, i, "max_range must be positive")
    check(g.min_range >= 0 and g.min_range <= g.max_range, i, "min_range must be in 0..max_range")
    check(g.fov >= 0, i, "fov must be ≥ 0")
    check(is_integer(g.rays) and g.rays >= 1, i, "rays must be an integer ≥ 1")

    check(
      is_integer(g.max_bounces) and g.max_bounces in 0..@max_bounces,
      i,
      "max_bounces must be an integer from 0 to #{@max_bounces}"
    )

    check(is_integer(g.ring) and g.ring >= -1, i, "ring must be an integer ≥ -1")
    check(g.noise_std >= 0 and g.noise_prop >= 0, i, "noise_std and noise_prop must be ≥ 0")
    check(g.spike_magnitude >= 0, i, "spike_magnitude must be ≥ 0")

    check(g.dropout >= 0 and g.dropout <= 1, i, "dropout must be a probability")
    check(g.spike >= 0 and g.spike <= 1, i, "spike must be a probability")

    g
  end

  defp group_params(other, i),
    do: raise(ArgumentError, "group #{i}: expected a map, got #{inspect(other)}")

  defp check(true, _i, _message), do: :ok
  defp check(false, i, message), do: raise(ArgumentError, "group #{i}: #{message}")

  # -2.0: every hit echoes (the C side skips the normal)
  defp cos_critical(angle) when angle >= @half_pi - 1.0e-12, do: -2.0
  defp cos_critical(angle), do: :math.cos(angle)

  defp cos_half_fov(fov) when fov >= @two_pi, do: -1.0
  defp cos_half_fov(fov), do: :math.cos(fov / 2)

  defp sin_half_fov(fov) when fov >= @two_pi, do: 0.0
  defp sin_half_fov(fov), do: :math.sin(fov / 2)
end
