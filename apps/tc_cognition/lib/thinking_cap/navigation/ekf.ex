defmodule ThinkingCap.Navigation.EKF do
  @moduledoc """
  An extended Kalman filter for the pose `{x, y, θ}` of a mobile robot in
  the world frame (REP-103: x forward, y left, θ counter-clockwise; m, rad),
  driven by odometry and corrected by range–bearing detections of known
  beacons. Pure functions on a struct: no process, no randomness.

      ekf = EKF.new({1.0, 1.0, 0.0}, EKF.diagonal(0.1, 0.1, 0.05))
      ekf = EKF.predict(ekf, EKF.relative(odom_before, odom_now), slip: 0.01, turn_slip: 0.02)
      {:accepted, ekf, _d2} = EKF.update_beacon(ekf, %{range: 3.2, bearing: 0.4}, {4.0, 2.5}, {0.02, 0.02})

  ## Prediction

  The odometry delta `{dx, dy, dθ}` is the motion between two odometry
  readings expressed in the robot frame of the first one (`relative/2`):
  it does not depend on where the odometry frame started, so the odometry
  of a robot that believes it started at `{0, 0, 0}` drives a filter in the
  world frame. The pose moves by composition (`motion/2`); the covariance
  by `F P Fᵀ + G Q Gᵀ` with `F`, `G` the Jacobians of the composition with
  respect to the pose and the delta (`motion_jacobians/2`).

  The motion noise `Q` (robot frame, diagonal) grows with the distance `d`
  and the turn `|dθ|` of the step, as in the RDF's `odometry_error`:

    * along x: `slip² · d + floor_xy²`;
    * along y: `floor_xy²`;
    * heading: `turn_slip² · |dθ| + drift² · d + floor_θ²`.

  `slip` (m per √m) and `turn_slip` (rad per √rad) are the standard
  deviations after one metre driven and one radian turned; `drift` (rad per
  √m) is heading uncertainty gained while driving straight (unequal wheels,
  uneven floor); `floor: {σ_xy, σ_θ}` is added at every prediction so that
  the covariance never stops growing while the robot stands still and
  stays invertible (it is per step: at a higher odometry rate use a smaller
  floor). Defaults: `slip: 0.01, turn_slip: 0.02, drift: 0.02, floor:
  {0.001, 0.001}`.

  ## Beacon update

  `update_beacon/5` is the standard range–bearing update: the predicted
  measurement `h(x)` (`measure/3`), its Jacobian `H` (`measurement_jacobian/3`),
  the innovation with its bearing normalised to (−π, π], and the gain
  `K = P Hᵀ S⁻¹` with `S = H P Hᵀ + R`. A detection whose squared
  Mahalanobis distance `νᵀ S⁻¹ ν` exceeds the gate (default 13.8, the
  99.9 % point of χ² with 2 degrees of freedom) is rejected as an outlier
  and leaves the filter unchanged. The covariance is updated in Joseph form,
  `(I − KH) P (I − KH)ᵀ + K R Kᵀ`, and symmetrised, so that it stays
  symmetric positive definite.

  Detections name their beacon (`id`), so data association is by name
  against a beacon map `%{id => {x, y}}` (`update_beacons/5`).

  Matrices are tuples of row tuples: the covariance is
  `{{σxx, σxy, σxθ}, {σyx, σyy, σyθ}, {σθx, σθy, σθθ}}`.
  """

  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @enforce_keys [:pose, :covariance]
  defstruct [:pose, :covariance]

  @type pose :: {float(), float(), float()}
  @type delta :: {float(), float(), float()}
  @type point :: {float(), float()}
  @type matrix :: tuple()
  @type t :: %__MODULE__{pose: pose(), covariance: matrix()}
  @type noise :: keyword() | map()
  @type detection :: %{
          required(:range) => number(),
          required(:bearing) => number(),
          optional(any()) => any()
        }

  @default_gate 13.8

  @doc """
  A filter at `pose` with covariance `covariance` (a 3×3 matrix as a tuple
  of row tuples or a list of row lists).
  """
  @spec new({number(), number(), number()}, matrix() | [[number()]]) :: t()
  def new({x, y, th}, covariance) do
    cov = to_matrix(covariance)

    unless tuple_size(cov) == 3 and Enum.all?(Tuple.to_list(cov), &(tuple_size(&1) == 3)),
      do:
        raise(ArgumentError, "EKF covariance: expected a 3×3 matrix, got #{inspect(covariance)}")

    %__MODULE__{pose: {x * 1.0, y * 1.0, normalize_angle(th * 1.0)}, covariance: symmetrise(cov)}
  end

  @doc "A diagonal covariance from the standard deviations of x, y and θ."
  @spec diagonal(number(), number(), number()) :: matrix()
  def diagonal(sx, sy, sth),
    do: {{sx * sx * 1.0, 0.0, 0.0}, {0.0, sy * sy * 1.0, 0.0}, {0.0, 0.0, sth * sth * 1.0}}

  @doc "The covariance as a list of row lists (JSON-friendly)."
  @spec covariance_list(t()) :: [[float()]]
  def covariance_list(%__MODULE__{covariance: cov}),
    do: cov |> Tuple.to_list() |> Enum.map(&Tuple.to_list/1)

  @doc "The standard deviations `{σx, σy, σθ}` (square roots of the covariance's diagonal)."
  @spec sigmas(t()) :: {float(), float(), float()}
  def sigmas(%__MODULE__{covariance: cov}),
    do: {sqrt(at(cov, 0, 0)), sqrt(at(cov, 1, 1)), sqrt(at(cov, 2, 2))}

  @doc """
  The motion from odometry pose `prev` to odometry pose `now`, in the robot
  frame at `prev`: `{dx, dy, dθ}` with `dθ` normalised to (−π, π].
  """
  @spec relative({number(), number(), number()}, {number(), number(), number()}) :: delta()
  defdelegate relative(prev, now), to: ThinkingCap.Geometry

  @doc "The pose reached from `pose` by the robot-frame motion `delta` (pose composition)."
  @spec motion(pose(), delta()) :: pose()
  defdelegate motion(pose, delta), to: ThinkingCap.Geometry, as: :compose

  @doc """
  The Jacobians `{F, G}` of `motion/2` with respect to the pose (3×3) and
  to the delta (3×3), at `pose` and `delta`.
  """
  @spec motion_jacobians(pose(), delta()) :: {matrix(), matrix()}
  def motion_jacobians({_x, _y, th}, {dx, dy, _dth}) do
    {c, s} = {:math.cos(th), :math.sin(th)}
    f = {{1.0, 0.0, -s * dx - c * dy}, {0.0, 1.0, c * dx - s * dy}, {0.0, 0.0, 1.0}}
    g = {{c, -s, 0.0}, {s, c, 0.0}, {0.0, 0.0, 1.0}}
    {f, g}
  end

  @doc """
  Moves the filter by the odometry delta `{dx, dy, dθ}` (robot frame, see
  `relative/2`) and grows its covariance by the motion noise (options
  `slip`, `turn_slip`, `drift`, `floor`, see the moduledoc).
  """
  @spec predict(t(), delta(), noise()) :: t()
  def predict(%__MODULE__{pose: pose, covariance: p}, {dx, dy, dth} = delta, noise \\ []) do
    {slip, turn_slip, drift, {fxy, fth}} = noise_params(noise)
    d = :math.sqrt(dx * dx + dy * dy)

    q =
      {{slip * slip * d + fxy * fxy, 0.0, 0.0}, {0.0, fxy * fxy, 0.0},
       {0.0, 0.0, turn_slip * turn_slip * abs(dth) + drift * drift * d + fth * fth}}

    {f, g} = motion_jacobians(pose, delta)
    p = add(mul(mul(f, p), transpose(f)), mul(mul(g, q), transpose(g)))
    %__MODULE__{pose: motion(pose, delta), covariance: symmetrise(p)}
  end

  @doc "Adds `extra` (3×3) to the covariance, keeping the pose: more doubt, e.g. for a lost filter."
  @spec inflate(t(), matrix()) :: t()
  def inflate(%__MODULE__{covariance: p} = ekf, extra),
    do: %{ekf | covariance: symmetrise(add(p, to_matrix(extra)))}

  @doc """
  The range and bearing `{r, b}` at which a sensor at `sensor_pose` on a
  robot at `pose` sees a beacon at `beacon` (`b` relative to the sensor's
  heading, normalised).
  """
  @spec measure(pose(), point(), pose()) :: {float(), float()}
  def measure(pose, beacon, sensor_pose \\ {0.0, 0.0, 0.0}) do
    {dx, dy, _sxth, _syth, th} = geometry(pose, beacon, sensor_pose)
    {_px, _py, pth} = sensor_pose
    {:math.sqrt(dx * dx + dy * dy), normalize_angle(:math.atan2(dy, dx) - th - pth)}
  end

  @doc """
  The 2×3 Jacobian of `measure/3` (range, bearing) with respect to the
  robot pose `{x, y, θ}`.
  """
  @spec measurement_jacobian(pose(), point(), pose()) :: matrix()
  def measurement_jacobian(pose, beacon, sensor_pose \\ {0.0, 0.0, 0.0}) do
    {dx, dy, sxth, syth, _th} = geometry(pose, beacon, sensor_pose)
    q = max(dx * dx + dy * dy, 1.0e-12)
    r = :math.sqrt(q)

    {{-dx / r, -dy / r, -(dx * sxth + dy * syth) / r},
     {dy / q, -dx / q, (dy * sxth - dx * syth) / q - 1.0}}
  end

  # the beacon relative to the sensor and the derivatives of the sensor's
  # world position with respect to θ
  defp geometry({x, y, th}, {bx, by}, {px, py, _pth}) do
    {c, s} = {:math.cos(th), :math.sin(th)}
    {sx, sy} = {x + c * px - s * py, y + s * px + c * py}
    {bx - sx, by - sy, -s * px - c * py, c * px - s * py, th}
  end

  @doc """
  Corrects the filter with one range–bearing detection of the beacon at
  `beacon` (`{x, y}`), the measurement noise being `{σ_range, σ_bearing}`.

  Options: `gate` (squared Mahalanobis distance beyond which the detection
  is rejected, default #{@default_gate}; `:infinity` accepts everything),
  `sensor_pose` (`{x, y, yaw}` of the sensor on the robot, default
  `{0, 0, 0}`).

  Returns `{:accepted, ekf, d²}` or, for an outlier, `{:rejected, ekf, d²}`
  with the filter unchanged (`d²` is `:infinity` when the sensor stands on
  the beacon, where the bearing is undefined).
  """
  @spec update_beacon(t(), detection(), point(), {number(), number()}, keyword()) ::
          {:accepted | :rejected, t(), float() | :infinity}
  def update_beacon(
        %__MODULE__{pose: pose, covariance: p} = ekf,
        %{range: z_r, bearing: z_b},
        beacon,
        {s_r, s_b},
        opts \\ []
      ) do
    gate = Keyword.get(opts, :gate, @default_gate)
    sensor_pose = Keyword.get(opts, :sensor_pose, {0.0, 0.0, 0.0})
    {r_hat, b_hat} = measure(pose, beacon, sensor_pose)

    if r_hat < 1.0e-6 do
      # the sensor is on the beacon: no bearing to speak of
      {:rejected, ekf, :infinity}
    else
      h = measurement_jacobian(pose, beacon, sensor_pose)
      r = {{s_r * s_r * 1.0, 0.0}, {0.0, s_b * s_b * 1.0}}
      pht = mul(p, transpose(h))
      s = add(mul(h, pht), r)
      s_inv = inverse2(s)
      nu = {{z_r - r_hat}, {normalize_angle(z_b - b_hat)}}
      d2 = at(mul(mul(transpose(nu), s_inv), nu), 0, 0)

      if gate != :infinity and d2 > gate do
        {:rejected, ekf, d2}
      else
        k = mul(pht, s_inv)
        dx = mul(k, nu)
        {x, y, th} = pose
        pose = {x + at(dx, 0, 0), y + at(dx, 1, 0), normalize_angle(th + at(dx, 2, 0))}
        i_kh = sub(identity3(), mul(k, h))
        p = add(mul(mul(i_kh, p), transpose(i_kh)), mul(mul(k, r), transpose(k)))
        {:accepted, %__MODULE__{pose: pose, covariance: symmetrise(p)}, d2}
      end
    end
  end

  @doc """
  Applies every detection whose `id` is in `beacons` (`%{id => {x, y}}`),
  one after the other, with `update_beacon/5` (same options). Detections of
  unknown beacons are ignored. Returns the filter, the number of accepted
  detections and the ids of the rejected ones.
  """
  @spec update_beacons(t(), [map()], %{term() => point()}, {number(), number()}, keyword()) ::
          {t(), non_neg_integer(), [term()]}
  def update_beacons(ekf, detections, beacons, noise, opts \\ []) do
    Enum.reduce(detections, {ekf, 0, []}, fn detection, {ekf, used, rejected} ->
      case Map.fetch(beacons, Map.get(detection, :id)) do
        {:ok, at} ->
          case update_beacon(ekf, detection, at, noise, opts) do
            {:accepted, ekf, _} -> {ekf, used + 1, rejected}
            {:rejected, ekf, _} -> {ekf, used, rejected ++ [detection.id]}
          end

        :error ->
          {ekf, used, rejected}
      end
    end)
  end

  @doc """
  The pose that best explains a set of detections alone (weighted least
  squares by Gauss–Newton, starting from `guess`): a fresh fix for a filter
  that lost itself. Needs detections of at least two beacons of `beacons`
  (`%{id => {x, y}}`); options `sensor_pose`, `iterations` (default 20).

  Returns `{:ok, ekf, χ²}` with the fitted pose, its covariance
  `(Σ Hᵀ R⁻¹ H)⁻¹` and the weighted squared residual (about 2n − 3 for n
  consistent detections), or `{:error, :too_few}` /
  `{:error, :no_fix}` (the geometry does not fix the pose, or no
  convergence).
  """
  @spec locate([map()], %{term() => point()}, {number(), number()}, pose(), keyword()) ::
          {:ok, t(), float()} | {:error, :too_few | :no_fix}
  def locate(detections, beacons, {s_r, s_b}, guess, opts \\ []) do
    sensor_pose = Keyword.get(opts, :sensor_pose, {0.0, 0.0, 0.0})
    pairs = for %{id: id} = d <- detections, Map.has_key?(beacons, id), do: {d, beacons[id]}
    weights = {1.0 / (s_r * s_r), 1.0 / (s_b * s_b)}

    if length(Enum.uniq_by(pairs, &elem(&1, 1))) < 2 do
      {:error, :too_few}
    else
      gauss_newton(pairs, weights, sensor_pose, guess, Keyword.get(opts, :iterations, 20))
    end
  end

  defp gauss_newton(pairs, weights, sensor_pose, {x, y, th} = pose, iterations) do
    {a, b, _chi2} = normal_equations(pairs, weights, sensor_pose, pose)

    case inverse3(a) do
      nil ->
        {:error, :no_fix}

      cov ->
        step = mul(cov, b)
        {dx, dy, dth} = {at(step, 0, 0), at(step, 1, 0), at(step, 2, 0)}
        pose = {x + dx, y + dy, normalize_angle(th + dth)}

        cond do
          abs(dx) + abs(dy) + abs(dth) < 1.0e-9 ->
            {_, _, chi2} = normal_equations(pairs, weights, sensor_pose, pose)
            {:ok, new(pose, cov), chi2}

          iterations <= 1 ->
            {:error, :no_fix}

          true ->
            gauss_newton(pairs, weights, sensor_pose, pose, iterations - 1)
        end
    end
  end

  defp normal_equations(pairs, {w_r, w_b}, sensor_pose, pose) do
    zero = {{0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}}
    w = {{w_r, 0.0}, {0.0, w_b}}

    Enum.reduce(pairs, {zero, {{0.0}, {0.0}, {0.0}}, 0.0}, fn {d, beacon}, {a, b, chi2} ->
      {r_hat, b_hat} = measure(pose, beacon, sensor_pose)
      h = measurement_jacobian(pose, beacon, sensor_pose)
      {nr, nb} = {d.range - r_hat, normalize_angle(d.bearing - b_hat)}
      htw = mul(transpose(h), w)

      {add(a, mul(htw, h)), add(b, mul(htw, {{nr}, {nb}})), chi2 + nr * nr * w_r + nb * nb * w_b}
    end)
  end

  ## noise

  defp noise_params(noise) do
    noise = Map.new(noise)
    floor = Map.get(noise, :floor, {0.001, 0.001})

    {Map.get(noise, :slip, 0.01) * 1.0, Map.get(noise, :turn_slip, 0.02) * 1.0,
     Map.get(noise, :drift, 0.02) * 1.0, floor}
  end

  ## small matrices: tuples of row tuples

  defp to_matrix(m) when is_list(m), do: m |> Enum.map(&to_row/1) |> List.to_tuple()
  defp to_matrix(m) when is_tuple(m), do: m |> Tuple.to_list() |> to_matrix()
  defp to_row(r) when is_list(r), do: r |> Enum.map(&(&1 * 1.0)) |> List.to_tuple()
  defp to_row(r) when is_tuple(r), do: r |> Tuple.to_list() |> to_row()

  defp at(m, i, j), do: m |> elem(i) |> elem(j)

  defp rows(m), do: Tuple.to_list(m)

  defp transpose(m) do
    n = tuple_size(elem(m, 0))
    List.to_tuple(for j <- 0..(n - 1), do: List.to_tuple(for row <- rows(m), do: elem(row, j)))
  end

  defp mul(a, b) do
    cols = rows(transpose(b))

    List.to_tuple(
      for row <- rows(a), do: List.to_tuple(for col <- cols, do: dot(row, col, tuple_size(row)))
    )
  end

  defp dot(a, b, n), do: Enum.reduce(0..(n - 1), 0.0, &(&2 + elem(a, &1) * elem(b, &1)))

  defp add(a, b), do: zip_with(a, b, &+/2)
  defp sub(a, b), do: zip_with(a, b, &-/2)

  defp zip_with(a, b, f) do
    Enum.zip_with(rows(a), rows(b), fn ra, rb ->
      Enum.zip_with(Tuple.to_list(ra), Tuple.to_list(rb), f) |> List.to_tuple()
    end)
    |> List.to_tuple()
  end

  defp symmetrise(m), do: zip_with(m, transpose(m), &((&1 + &2) / 2))

  defp identity3, do: {{1.0, 0.0, 0.0}, {0.0, 1.0, 0.0}, {0.0, 0.0, 1.0}}

  defp inverse2({{a, b}, {c, d}}) do
    det = a * d - b * c
    {{d / det, -b / det}, {-c / det, a / det}}
  end

  defp inverse3({{a, b, c}, {d, e, f}, {g, h, i}}) do
    co =
      {{e * i - f * h, c * h - b * i, b * f - c * e},
       {f * g - d * i, a * i - c * g, c * d - a * f},
       {d * h - e * g, b * g - a * h, a * e - b * d}}

    det = a * elem(elem(co, 0), 0) + b * elem(elem(co, 1), 0) + c * elem(elem(co, 2), 0)
    scale = Enum.max(Enum.map([a, e, i], &abs/1))

    if scale == 0 or abs(det) <= 1.0e-12 * scale * scale * scale,
      do: nil,
      else: zip_with(co, co, fn v, _ -> v / det end)
  end

  defp sqrt(v) when v > 0, do: :math.sqrt(v)
  defp sqrt(_), do: 0.0
end
