defmodule ThinkingCap.Navigation.Localizer do
  @moduledoc """
  Beacon localization as a ThinkingCap module (event-driven): an
  `ThinkingCap.Navigation.EKF` predicted by the robot's odometry and
  corrected by its beacon laser, publishing the robot's pose in the world
  frame of the WDF.

      [name: :localizer, module: ThinkingCap.Navigation.Localizer, activity: :event,
       params: [initial: :dock, initial_sigma: {0.1, 0.05}]]

  It subscribes to `{odometry, robot, :_}` and `{beacons, robot, :_}`
  (the sensor names of the RDF). On odometry
  (`%{pose: {x, y, θ}, stamp: t, ...}` in the odometry frame) it predicts
  with the motion since the previous odometry reading (`EKF.relative/2`; the
  first reading only sets the reference); on beacon detections
  (`%{detections: [%{id:, range:, bearing:}], stamp: t}`) it corrects with
  every detection of a beacon of the WDF, associated by `id`, rejecting
  outliers with the EKF's Mahalanobis gate. Detections are applied at the
  latest odometry prediction (no extrapolation to their stamp).

  It writes the latest-value tuple (key `{:pose, robot}`)

      {:pose, robot, %{pose: {x, y, θ}, covariance: [[..], [..], [..]],
                      stamp: t, beacons_used: n}}

  after every beacon reading and, between them, after an odometry
  prediction when at least `publish_period` (default 0.1 s) of stamp has
  passed since the last publication. `covariance` is the 3×3 covariance of
  `{x, y, θ}` as a list of rows; `beacons_used` the number of detections
  accepted by the reading that produced it (0 after a prediction).

  ## Parameters

    * `odometry` - the odometry sensor's tag (default: the name of the
      RDF's sensor of type `:odometry`, else `:odom`);
    * `beacons` - the beacon sensor's tag (default `:beacons`);
    * `initial` - the start pose `{x, y, θ}` or `{x, y}`, or the name of a
      waypoint of the WDF (default `{0, 0, 0}`; a waypoint without a
      heading faces θ = 0);
    * `initial_sigma` - `{σ_xy, σ_θ}` of the start pose (default `{0.1, 0.05}`);
    * `slip`, `turn_slip` - motion noise (default: the RDF's
      `odometry_error`, else the EKF's defaults); `drift`, `floor` - see
      `ThinkingCap.Navigation.EKF`;
    * `range_sigma`, `bearing_sigma` - detection noise (default: the beacon
      sensor's `noise.stddev` in the RDF, at least 0.005; else 0.05 m and
      0.05 rad);
    * `sensor_pose` - the beacon sensor's pose on the robot (default: the
      RDF's, else `{0, 0, 0}`);
    * `gate` - the Mahalanobis gate (default 13.8);
    * `publish_period` - seconds of stamp between publications after
      predictions (default 0.1);
    * `lost_after`, `lost_sigma` - when `lost_after` (default 5) beacon
      readings in a row had most of their detections (at least two)
      rejected, the estimate is taken to be lost: the pose is fixed afresh
      from the latest reading alone (`EKF.locate/5`) and, if that fix
      explains the detections, the filter restarts from it with its
      covariance grown by `lost_sigma` `{σ_xy, σ_θ}` (default
      `{0.05, 0.05}`), so that a filter started too confident, or a robot
      that was carried away, recovers. `lost_after: :never`
      disables it.

  The beacon map is the WDF's `beacons` (`context.wdf`); without a WDF the
  filter only integrates odometry.

  Deployed with standbys, it hands its filter over (`handoff/1`): a
  localizer started on a standby after a failover resumes from the last
  estimate and the motion since, not from `initial`.
  """

  use ThinkingCap.Module

  alias ThinkingCap.Navigation.EKF
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples

  @doc """
  Reads the WDF (beacons, waypoints) and the RDF (noise defaults) of the
  context, builds the filter and subscribes to the odometry and beacon
  tuples of the context's robot. Raises `ArgumentError` on an unreadable
  description or an unknown waypoint.
  """
  @impl true
  @spec init(keyword() | map(), ThinkingCap.Module.context()) ::
          {ThinkingCap.Module.actions(), map()}
  def init(params, context) do
    params = Map.new(params || [])
    robot = context.robot
    wdf = read_wdf(Map.get(context, :wdf))
    rdf = read_rdf(Map.get(context, :rdf))
    odometry = Map.get(params, :odometry, Description.sensor_name(rdf, :odometry, :odom))
    beacon_tag = Map.get(params, :beacons, :beacons)

    {x, y, th} = initial_pose(Map.get(params, :initial, {0.0, 0.0, 0.0}), wdf)
    {s_xy, s_th} = Map.get(params, :initial_sigma, {0.1, 0.05})
    sensor = beacon_sensor(rdf, beacon_tag)
    odometry_error = if rdf, do: rdf.odometry_error, else: %{}

    motion_noise =
      [:slip, :turn_slip]
      |> Enum.flat_map(
        &if(is_number(odometry_error[&1]), do: [{&1, odometry_error[&1]}], else: [])
      )
      |> Map.new()
      |> Map.merge(Map.take(params, [:slip, :turn_slip, :drift, :floor]))

    sd = sensor_stddev(sensor)

    state = %{
      robot: robot,
      odometry: odometry,
      beacon_tag: beacon_tag,
      beacons: beacon_map(wdf),
      ekf: EKF.new({x, y, th}, EKF.diagonal(s_xy, s_xy, s_th)),
      motion_noise: motion_noise,
      sensor_noise: {Map.get(params, :range_sigma, sd), Map.get(params, :bearing_sigma, sd)},
      update_opts: [
        gate: Map.get(params, :gate, 13.8),
        sensor_pose: Map.get(params, :sensor_pose, (sensor && sensor[:pose]) || {0.0, 0.0, 0.0})
      ],
      publish_period: Map.get(params, :publish_period, 0.1),
      lost_after: Map.get(params, :lost_after, 5),
      lost_sigma: Map.get(params, :lost_sigma, {0.05, 0.05}),
      rejected_readings: 0,
      last_odometry: nil,
      last_published: nil
    }

    {[subscribe: Tuples.reading(odometry, robot), subscribe: Tuples.reading(beacon_tag, robot)],
     resume(state, Map.get(context, :handoff))}
  end

  # After a failover: the estimate and the odometry reading it was taken
  # at, so the first odometry here predicts over the motion since then.
  defp resume(state, %{ekf: %EKF{} = ekf, last_odometry: odom}),
    do: %{state | ekf: ekf, last_odometry: odom}

  defp resume(state, _handoff), do: state

  @doc """
  What a standby needs to carry on (`c:ThinkingCap.Module.handoff/1`): the
  filter and the odometry reading it is up to date with.
  """
  @impl true
  @spec handoff(map()) :: map()
  def handoff(state), do: %{ekf: state.ekf, last_odometry: state.last_odometry}

  @doc "Predicts on odometry, corrects on beacon detections, publishes the pose."
  @impl true
  @spec handle_tuple(tuple(), map()) :: {ThinkingCap.Module.actions(), map()}
  def handle_tuple(
        Tuples.reading(tag, robot, %{pose: odom} = payload),
        %{odometry: tag, robot: robot} = state
      ) do
    stamp = Map.get(payload, :stamp)

    case state.last_odometry do
      nil ->
        publish(%{state | last_odometry: odom}, stamp, 0)

      previous ->
        ekf = EKF.predict(state.ekf, EKF.relative(previous, odom), state.motion_noise)
        state = %{state | ekf: ekf, last_odometry: odom}

        if due?(state, stamp), do: publish(state, stamp, 0), else: {[], state}
    end
  end

  def handle_tuple(
        Tuples.reading(tag, robot, %{detections: detections} = payload),
        %{beacon_tag: tag, robot: robot} = state
      ) do
    {ekf, used, rejected} = update(state, state.ekf, detections)
    lost? = length(rejected) >= 2 and length(rejected) > used
    count = if lost?, do: state.rejected_readings + 1, else: 0

    {ekf, used, count} =
      if lost? and state.lost_after != :never and count >= state.lost_after,
        do: relocate(state, ekf, used, detections),
        else: {ekf, used, count}

    publish(%{state | ekf: ekf, rejected_readings: count}, Map.get(payload, :stamp), used)
  end

  def handle_tuple(_tuple, state), do: {[], state}

  # a fresh fix from this reading alone, when it explains the detections
  defp relocate(state, ekf, used, detections) do
    case EKF.locate(detections, state.beacons, state.sensor_noise, ekf.pose, state.update_opts) do
      {:ok, fix, chi2} ->
        n = Enum.count(detections, &Map.has_key?(state.beacons, Map.get(&1, :id)))

        gate = state.update_opts[:gate]

        if gate == :infinity or chi2 <= gate * n do
          {s_xy, s_th} = state.lost_sigma
          {EKF.inflate(fix, EKF.diagonal(s_xy, s_xy, s_th)), n, 0}
        else
          {ekf, used, 0}
        end

      {:error, _} ->
        {ekf, used, 0}
    end
  end

  defp update(state, ekf, detections),
    do: EKF.update_beacons(ekf, detections, state.beacons, state.sensor_noise, state.update_opts)

  defp due?(%{last_published: nil}, _stamp), do: true
  defp due?(_state, nil), do: true

  defp due?(%{last_published: last, publish_period: period}, stamp),
    do: stamp - last >= period - 1.0e-9

  defp publish(state, stamp, used) do
    payload = %{
      pose: state.ekf.pose,
      covariance: EKF.covariance_list(state.ekf),
      stamp: stamp,
      beacons_used: used
    }

    tuple = Tuples.pose(state.robot, payload)
    last = if is_number(stamp), do: stamp, else: state.last_published
    {[out: Tuples.keyed(tuple)], %{state | last_published: last}}
  end

  ## descriptions

  defp read_wdf(nil), do: nil

  defp read_wdf(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, %ThinkingCap.Config.WDF{} = wdf} ->
        wdf

      {:ok, _other} ->
        raise ArgumentError, "localizer: #{path} is not a world description (.wdf)"

      {:error, errors} ->
        raise ArgumentError, "localizer: " <> ThinkingCap.Config.format_errors(errors)
    end
  end

  defp read_rdf(nil), do: nil

  defp read_rdf(path) do
    case Description.load(path) do
      {:ok, description} -> description
      {:error, message} -> raise ArgumentError, "localizer: " <> message
    end
  end

  defp beacon_map(nil), do: %{}
  defp beacon_map(wdf), do: Map.new(wdf.beacons, &{&1.name, &1.at})

  defp initial_pose({x, y, th}, _wdf), do: {x, y, th}
  defp initial_pose({x, y}, _wdf), do: {x, y, 0.0}

  defp initial_pose(name, wdf) when is_atom(name) do
    waypoints = if wdf, do: wdf.waypoints, else: []

    case Enum.find(waypoints, &(&1.name == name)) do
      nil ->
        known = Enum.map_join(waypoints, ", ", &inspect(&1.name))

        raise ArgumentError,
              "localizer: initial: #{inspect(name)} is not a waypoint of the world" <>
                if(known == "", do: " (no waypoints)", else: " (waypoints: #{known})")

      %{at: at} ->
        initial_pose(at, wdf)
    end
  end

  defp beacon_sensor(nil, _tag), do: nil

  defp beacon_sensor(rdf, tag) do
    Enum.find(rdf.sensors, &(&1.name == tag)) ||
      Enum.find(rdf.sensors, &(&1.type == :beacon_laser))
  end

  defp sensor_stddev(%{noise: %{stddev: sd}}) when is_number(sd), do: max(sd, 0.005)
  defp sensor_stddev(_), do: 0.05
end
