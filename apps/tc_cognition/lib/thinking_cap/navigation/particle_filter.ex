defmodule ThinkingCap.Navigation.ParticleFilter do
  @moduledoc """
  Monte Carlo localization on an occupancy grid, in the manner of ROS's
  AMCL: a set of pose hypotheses (particles) moved by the odometry motion
  model, weighed by how well a laser scan fits the map from each (a
  likelihood field), resampled; augmented MCL's two averages of the fit
  (`w_slow`, `w_fast`) bring in particles drawn anywhere in free space
  when the fit falls short of what it was, and `relocalize/2` searches the
  whole map for the scan (a global correlative search) when the robot is
  lost. The numbers run in C (`c_src/tc_mcl.c`); this module holds the
  filter's parameters and bookkeeping. The injection is off by default
  (`max_injection: 0.0`, as AMCL's recovery alphas are): in a map with
  look-alike places, a box or a person in front of the laser makes the
  true pose fit worse than a thrown-in particle at a look-alike place,
  and the estimate jumped there; a robot really lost is found by
  `relocalize/2`.

  Sensor model (Probabilistic Robotics 6.4): a beam ending `d` metres from
  the nearest obstacle of the map scores `z_hit · exp(−d²/2σ²) + z_rand /
  range_max` (defaults σ 0.1 m, z_hit 0.9, z_rand 0.1); a beam without
  echo is skipped, and a particle off the map, in unknown space or inside
  an obstacle scores as noise. A beam ending in unknown space or off the
  map says nothing in a map still being built; in a map given whole
  (`set_map/4` with `strict: true`) it is scored by its distance to the
  nearest obstacle, and off the map as noise: a laser stops only at what
  the map holds.

  Motion model (table 5.6, sample_motion_model_odometry): a move is a
  turn, a straight line and a turn, each with noise of variance
  `α1·rot² + α2·trans²` (turns) and `α3·trans² + α4·rot²` (the line).

  The value is mutable (NIF resources): functions change it in place and
  return it with its bookkeeping updated.
  """

  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Navigation.Core.GridNif
  import ThinkingCap.Geometry, only: [angle_diff: 2]

  defstruct [
    :set,
    :field,
    :map,
    strict: false,
    count: 500,
    model: {0.1, 0.9, 0.1, 8.0},
    alphas: {0.1, 0.02, 0.05, 0.01},
    alpha_slow: 0.001,
    alpha_fast: 0.1,
    max_injection: 0.0,
    w_slow: nil,
    w_fast: nil,
    free_poses: <<>>,
    n_eff: 0.0
  ]

  @type pose :: {float(), float(), float()}
  @type t :: %__MODULE__{}

  @doc """
  A filter of `count` particles (default 500) spread around `pose` with
  standard deviations `{σ_xy, σ_θ}`. Options: `count`, `seed` (default 1),
  `sigma_hit`, `z_hit`, `z_rand`, `range_max` (the sensor model), `alphas`
  (`{α1, α2, α3, α4}`, the motion model), `max_injection` (the largest
  share of particles augmented MCL may throw in at a resampling, default
  0).
  """
  @spec new(pose(), {number(), number()}, keyword()) :: t()
  def new({x, y, th}, {s_xy, s_th}, opts \\ []) do
    count = Keyword.get(opts, :count, 500)
    base = %__MODULE__{count: count}

    model =
      {Keyword.get(opts, :sigma_hit, 0.1) * 1.0, Keyword.get(opts, :z_hit, 0.9) * 1.0,
       Keyword.get(opts, :z_rand, 0.1) * 1.0, Keyword.get(opts, :range_max, 8.0) * 1.0}

    poses =
      :binary.copy(
        <<x * 1.0::float-native, y * 1.0::float-native, th * 1.0::float-native>>,
        count
      )

    set = GridNif.pf_new(poses, Keyword.get(opts, :seed, 1))

    :ok =
      GridNif.pf_spread(set, {x * 1.0, y * 1.0, th * 1.0}, {s_xy * 1.0, s_xy * 1.0, s_th * 1.0})

    alphas = Keyword.get(opts, :alphas, base.alphas)
    injection = Keyword.get(opts, :max_injection, base.max_injection) * 1.0
    %{base | set: set, model: model, alphas: alphas, max_injection: injection}
  end

  @doc """
  Takes a map: the likelihood field is built from its cells of occupancy
  at least `threshold` (option, default 50), and, when `max_injection` is
  above 0, a few thousand poses in its known free space are drawn (with
  `seed`) for the particles augmented MCL brings in. Option `strict`
  (default false): the map is given whole, so a beam ending in its
  unknown space or off it is scored, not passed over.
  """
  @spec set_map(t(), OccupancyGrid.t(), integer(), keyword()) :: t()
  def set_map(%__MODULE__{} = pf, %OccupancyGrid{} = map, seed \\ 1, opts \\ []) do
    {ox, oy} = map.origin
    strict = Keyword.get(opts, :strict, false)

    field =
      GridNif.field_new(
        map.data,
        map.width,
        map.height,
        map.resolution,
        ox * 1.0,
        oy * 1.0,
        Keyword.get(opts, :threshold, 50),
        if(strict, do: 1, else: 0)
      )

    # (drawn only when augmented MCL may throw particles in: a large map
    # has millions of free cells)
    poses = if pf.max_injection > 0, do: free_poses(map, 4000, seed), else: <<>>
    %{pf | field: field, map: map, strict: strict, free_poses: poses}
  end

  defp free_poses(%OccupancyGrid{} = map, n, seed) do
    free = for {i, _} <- :binary.matches(map.data, <<0>>), do: i
    count = length(free)

    if count == 0 do
      <<>>
    else
      cells = List.to_tuple(free)
      rng = :rand.seed_s(:exsss, {seed, 13, 7})
      {ox, oy} = map.origin

      {poses, _} =
        Enum.map_reduce(1..n, rng, fn _, rng ->
          {u, rng} = :rand.uniform_s(count, rng)
          {v, rng} = :rand.uniform_s(rng)
          i = elem(cells, u - 1)
          x = ox + (rem(i, map.width) + 0.5) * map.resolution
          y = oy + (div(i, map.width) + 0.5) * map.resolution
          th = (v - 0.5) * 2 * :math.pi()
          {<<x::float-native, y::float-native, th::float-native>>, rng}
        end)

      IO.iodata_to_binary(poses)
    end
  end

  @doc "Moves every particle by an odometry motion `{dx, dy, dθ}` in the robot frame."
  @spec move(t(), pose()) :: t()
  def move(%__MODULE__{} = pf, {dx, dy, dth}) do
    :ok = GridNif.pf_move(pf.set, {dx * 1.0, dy * 1.0, dth * 1.0}, pf.alphas)
    pf
  end

  @doc """
  Carries every particle by the rigid motion that takes pose `from` to
  pose `to`: the map's frame moved under the robot (a loop closed).
  """
  @spec transform(t(), pose(), pose()) :: t()
  def transform(%__MODULE__{} = pf, from, to) do
    :ok = GridNif.pf_transform(pf.set, floats(from), floats(to))
    pf
  end

  defp floats({x, y, th}), do: {x * 1.0, y * 1.0, th * 1.0}

  @doc """
  Weighs the particles by a scan (`beams`: a binary of native doubles
  `{x, y, angle, range}` per beam, the sensor's position and the beam's
  direction in the robot frame) and resamples when the effective number
  of particles falls under half, bringing in the share of free-space
  poses augmented MCL asks for. `temper` (in (0, 1], default 1) scales
  the scan's log-likelihood: below 1, hypotheses that one scan cannot
  tell apart live on for the next. Returns the filter and the mean
  per-beam likelihood of the scan over the particles. Without a map,
  nothing.
  """
  @spec sense(t(), binary(), float()) :: {t(), float()}
  def sense(pf, beams, temper \\ 1.0)
  def sense(%__MODULE__{field: nil} = pf, _beams, _temper), do: {pf, 0.0}

  def sense(%__MODULE__{} = pf, beams, temper) do
    {mean, n_eff, _known} = GridNif.pf_weigh(pf.set, pf.field, beams, pf.model, temper * 1.0)
    w_slow = average(pf.w_slow, mean, pf.alpha_slow)
    w_fast = average(pf.w_fast, mean, pf.alpha_fast)
    pf = %{pf | w_slow: w_slow, w_fast: w_fast, n_eff: n_eff}

    if n_eff < pf.count / 2 do
      share = max(0.0, 1.0 - w_fast / max(w_slow, 1.0e-12))
      :ok = GridNif.pf_resample(pf.set, min(share, pf.max_injection), pf.free_poses)
      {%{pf | n_eff: pf.count * 1.0}, mean}
    else
      {pf, mean}
    end
  end

  defp average(nil, x, _alpha), do: x
  defp average(avg, x, alpha), do: avg + alpha * (x - avg)

  @doc """
  The estimate: the weighted mean pose (circular mean heading) and the
  covariance of `{x, y, θ}` as a list of rows.
  """
  @spec estimate(t()) :: {pose(), [[float()]]}
  def estimate(%__MODULE__{} = pf) do
    {pose, covariance, _n_eff} = GridNif.pf_estimate(pf.set)
    {pose, covariance}
  end

  @doc """
  How well a scan fits the map from `pose`: the mean per-beam likelihood
  over the largest it can be (`z_hit + z_rand / range_max`), in [0, 1],
  and the share of the beams with an echo that ended on known map. nil
  without a map or without a beam to judge by.
  """
  @spec fit(t(), binary(), pose()) :: {float(), float()} | nil
  def fit(%__MODULE__{field: nil}, _beams, _pose), do: nil

  def fit(%__MODULE__{model: {_s, z_hit, z_rand, range_max} = model} = pf, beams, pose) do
    used = count_echoes(beams, range_max)

    if used == 0 do
      nil
    else
      {ll, known} = GridNif.field_score(pf.field, beams, model, pose)
      best = z_hit + z_rand / range_max
      {min(1.0, :math.exp(ll / used) / best), known / used}
    end
  end

  @doc """
  The share of a scan's beams that end on the map from `pose`: within
  `tolerance` metres (default 0.25) of an occupied cell. Judged are the
  beams with an echo ending on known map, unless they end within
  `tolerance` of unknown space or of the map's edge and not of an
  occupied cell (what stopped them the map does not know: a box in a
  rack's unknown inside, something past a map's open end), and the
  beams without one (range at least `range_max`) that pass an occupied
  cell of the map 0.5 m or more short of the range. Returns `{share,
  judged}`, or nil without a map or a beam to judge by. A beam ending in
  the open or missing a wall in its range is a misfit.
  """
  @spec hits(t(), binary(), pose(), float()) :: {float(), non_neg_integer()} | nil
  def hits(pf, beams, pose, tolerance \\ 0.25)
  def hits(%__MODULE__{field: nil}, _beams, _pose, _tolerance), do: nil

  def hits(%__MODULE__{} = pf, beams, pose, tolerance) do
    case GridNif.field_fit(pf.field, beams, pf.model, pose, tolerance * 1.0) do
      {_near, 0} -> nil
      {near, judged} -> {near / judged, judged}
    end
  end

  @doc """
  How much a scan contradicts the map from `pose`: the share of its beams
  (those with an echo, over known map) that pass through a wall of the
  map more than 0.25 m short of their end, in [0, 1], with the number of
  beams judged; nil without a map or a beam to judge by. A laser does not
  see through walls; a beam ending short of one (a box, a person the map
  does not hold) contradicts nothing.
  """
  @spec contradiction(t(), binary(), pose()) :: {float(), non_neg_integer()} | nil
  def contradiction(%__MODULE__{field: nil}, _beams, _pose), do: nil

  def contradiction(%__MODULE__{} = pf, beams, pose) do
    case GridNif.field_through(pf.field, beams, pf.model, pose) do
      {_through, 0} -> nil
      {through, judged} -> {through / judged, judged}
    end
  end

  defp count_echoes(beams, range_max) do
    for <<_x::float-native, _y::float-native, _a::float-native, r::float-native <- beams>>,
        r < range_max,
        reduce: 0,
        do: (n -> n + 1)
  end

  @doc """
  Searches the map for the scan (the whole map, or with `around: {{x,
  y}, r}` a square of half-side r round a point, and with `around: {{x,
  y}, r, {θ, half}}` only the headings within half of θ) and spreads the
  particles round what it found (`search/3`, then `relocalize_to/3`).
  Returns the filter and the best pose, or nil without a map.
  """
  @spec relocalize(t(), binary(), keyword()) :: {t(), pose() | nil}
  def relocalize(pf, beams, opts \\ [])
  def relocalize(%__MODULE__{field: nil} = pf, _beams, _opts), do: {pf, nil}

  def relocalize(%__MODULE__{} = pf, beams, opts),
    do: relocalize_to(pf, search(pf, beams, opts), opts)

  @doc """
  Searches the map for the scan without touching the particles: the
  `top` poses (default 60) of a lattice over the known free space
  (`step` metres, default 0.2, and `headings` headings, default 72; the
  whole map or the `around` box of `relocalize/3`) that fit it best,
  scored with a wider sensor model and at most one per place, each
  refined on finer lattices round it while they find better, and with
  the pose `from` (default the estimate: a robot that was not moved
  keeps its place if it fits best) and the poses of option `also`
  (default none: places an earlier search found, carried by the
  odometry since), refined likewise. Returns
  `[{log_likelihood, x, y, θ}]` scored with the filter's sensor model,
  best first; `[]` without a map.
  """
  @spec search(t(), binary(), keyword()) :: [{float(), float(), float(), float()}]
  def search(pf, beams, opts \\ [])
  def search(%__MODULE__{field: nil}, _beams, _opts), do: []

  def search(%__MODULE__{} = pf, beams, opts) do
    step = Keyword.get(opts, :step, 0.2)
    headings = Keyword.get(opts, :headings, 72)
    top = Keyword.get(opts, :top, 60)

    # the estimate (or the pose given) stays a candidate
    {x, y, th} = Keyword.get_lazy(opts, :from, fn -> elem(estimate(pf), 0) end)
    ll = score(pf, beams, {x, y, th})

    # the lattice scored with a wider sensor model: the pose nearest the
    # true one may be a half step and a half heading off it, and far beams
    # miss by more than sigma_hit; then the best of each place (others
    # within 0.5 m and 0.35 rad dropped), refined with the true model
    {sigma, z_hit, z_rand, range_max} = pf.model
    coarse = {max(sigma, 1.5 * step) * 1.0, z_hit, z_rand, range_max}
    turn = :math.pi() / headings

    pf.field
    |> GridNif.field_search(
      beams,
      coarse,
      step * 1.0,
      headings,
      5 * top,
      box(pf, opts[:around])
    )
    |> distinct(top)
    |> Enum.map(fn {_, x, y, th} -> {score(pf, beams, {x, y, th}), x, y, th} end)
    |> List.insert_at(0, {ll, x * 1.0, y * 1.0, th * 1.0})
    |> Kernel.++(
      for {x, y, th} <- Keyword.get(opts, :also, []),
          do: {score(pf, beams, {x, y, th}), x * 1.0, y * 1.0, th * 1.0}
    )
    |> Enum.map(fn c ->
      c
      |> then(&climb(pf, beams, &1, step / 2, turn, 4))
      |> then(&climb(pf, beams, &1, step / 6, turn / 3, 4))
    end)
    |> Enum.sort_by(&(-elem(&1, 0)))
  end

  @doc """
  Spreads the particles round the `candidates` of `search/3` (`{σ_xy,
  σ_θ}` option `sigma`, default `{0.1, 0.05}`), the better poses with
  more: in proportion to their likelihood over the best's, tempered (a
  scan alone may not tell two places apart: the moves to come will).
  Returns the filter and the best pose, or the filter unchanged and nil
  without a candidate.
  """
  @spec relocalize_to(t(), [{float(), float(), float(), float()}], keyword()) ::
          {t(), pose() | nil}
  def relocalize_to(pf, candidates, opts \\ [])
  def relocalize_to(%__MODULE__{} = pf, [], _opts), do: {pf, nil}

  def relocalize_to(%__MODULE__{} = pf, [{best_ll, bx, by, bth} | _] = found, opts) do
    {s_xy, s_th} = Keyword.get(opts, :sigma, {0.1, 0.05})
    weights = Enum.map(found, fn {ll, _, _, _} -> :math.exp(max((ll - best_ll) / 4, -30.0)) end)
    total = Enum.sum(weights)
    rng = :rand.seed_s(:exsss, {Keyword.get(opts, :seed, 1), 5, 5})

    {poses, _} =
      found
      |> Enum.zip(weights)
      |> Enum.flat_map(fn {{_, x, y, th}, w} ->
        List.duplicate({x, y, th}, max(1, round(w / total * pf.count)))
      end)
      |> Stream.cycle()
      |> Enum.take(pf.count)
      |> Enum.map_reduce(rng, fn {x, y, th}, rng ->
        {a, rng} = :rand.normal_s(rng)
        {b, rng} = :rand.normal_s(rng)
        {c, rng} = :rand.normal_s(rng)

        {<<x + s_xy * a::float-native, y + s_xy * b::float-native, th + s_th * c::float-native>>,
         rng}
      end)

    set = GridNif.pf_new(IO.iodata_to_binary(poses), Keyword.get(opts, :seed, 1))
    {%{pf | set: set, w_slow: nil, w_fast: nil}, {bx, by, bth}}
  end

  @doc """
  The log-likelihood of a scan from `pose` with the filter's sensor
  model (beams with an echo only); 0.0 without a map.
  """
  @spec score(t(), binary(), pose()) :: float()
  def score(%__MODULE__{field: nil}, _beams, _pose), do: 0.0

  def score(%__MODULE__{} = pf, beams, {x, y, th}) do
    {ll, _known} = GridNif.field_score(pf.field, beams, pf.model, {x * 1.0, y * 1.0, th * 1.0})
    ll
  end

  @doc "How many of a scan's beams have an echo (a range short of the model's `range_max`)."
  @spec echoes(t(), binary()) :: non_neg_integer()
  def echoes(%__MODULE__{model: {_, _, _, range_max}}, beams), do: count_echoes(beams, range_max)

  # the best `n` poses of a list best first, none within 0.5 m and 0.35 rad
  # of a better one
  defp distinct(found, n) do
    found
    |> Enum.reduce([], fn {_, x, y, th} = c, kept ->
      near =
        length(kept) >= n or
          Enum.any?(kept, fn {_, kx, ky, kth} ->
            (kx - x) ** 2 + (ky - y) ** 2 < 0.25 and
              abs(angle_diff(kth, th)) < 0.35
          end)

      if near, do: kept, else: [c | kept]
    end)
    |> Enum.reverse()
  end

  # the lattice's box: the whole map, or a square round a point
  defp box(%{map: map}, nil) do
    {ox, oy} = map.origin
    {ox, oy, ox + map.width * map.resolution, oy + map.height * map.resolution}
  end

  defp box(_pf, {{x, y}, r}), do: {x - r, y - r, x + r, y + r}

  defp box(_pf, {{x, y}, r, {th, half}}),
    do: {x - r, y - r, x + r, y + r, th * 1.0, max(half, 0.0) * 1.0}

  # the small lattice round a pose again and again while it finds better
  # (at most n more times): a pose beside a wall is pushed off it
  defp climb(pf, beams, candidate, half_step, half_turn, n) do
    better = refine(pf, beams, candidate, half_step, half_turn)

    if n == 0 or better == candidate,
      do: better,
      else: climb(pf, beams, better, half_step, half_turn, n - 1)
  end

  # the best pose of a small lattice round a found one (a third of the
  # search's steps)
  defp refine(pf, beams, {ll, x, y, th}, half_step, half_turn) do
    offsets = fn h -> [-h, -h / 3, h / 3, h] end

    for dx <- [0.0 | offsets.(half_step)],
        dy <- [0.0 | offsets.(half_step)],
        dth <- [0.0 | offsets.(half_turn)],
        reduce: {ll, x, y, th} do
      {best, _, _, _} = acc ->
        pose = {x + dx, y + dy, th + dth}
        {l, _known} = GridNif.field_score(pf.field, beams, pf.model, pose)
        if l > best, do: {l, x + dx, y + dy, th + dth}, else: acc
    end
  end

  @doc """
  The place the cloud holds most likely: the weighted mean pose (circular
  mean heading) of the particles within `radius` metres (default 1.0) of
  the particle of the largest weight, and their share of the weight. The
  mean of a cloud split between places stands nowhere; this stands at
  the likeliest of them.
  """
  @spec mode(t(), number()) :: {pose(), float()}
  def mode(%__MODULE__{} = pf, radius \\ 1.0), do: GridNif.pf_mode(pf.set, radius * 1.0)

  @doc "The particle of the largest weight."
  @spec best(t()) :: pose()
  def best(%__MODULE__{} = pf), do: GridNif.pf_best(pf.set)

  @doc "Up to `k` particles' poses, spread evenly over the set (for display)."
  @spec sample(t(), non_neg_integer()) :: [pose()]
  def sample(%__MODULE__{} = pf, k), do: GridNif.pf_sample(pf.set, k)
end
