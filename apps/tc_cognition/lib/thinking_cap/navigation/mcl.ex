defmodule ThinkingCap.Navigation.MCL do
  @moduledoc """
  Laser localization as an ADF module (event-driven): Monte Carlo
  localization (`ThinkingCap.Navigation.ParticleFilter`) against the map
  the robot has, without beacons.

      localization: [module: ThinkingCap.Navigation.MCL, activity: :event,
                     params: [initial: :dock, initial_sigma: {0.5, 0.3}]]

  **The map** is the WDF's (its walls, obstacles and closed doors, and
  its imported `map_server` map; the floor inside a WDF drawn with walls
  only counts as free). With an empty WDF it is the map builder's
  (`{:map, robot, %OccupancyGrid{}}`, from `ThinkingCap.Navigation.Mapper`),
  taken again at most every `map_every` seconds: simultaneous
  localization and mapping, the map built at this module's estimates and
  the estimates held to the map; until the first map comes the odometry
  alone moves the estimate. (A map being built knows little at first,
  and what it does not know says nothing: with a WDF, its map is the
  firmer ground.) When the map builder closes a loop
  (`{:map_correction, robot, %{from:, to:, frame:, map:}}`), the particles
  are carried by the move of the map's frame and the new map taken at
  once; every estimate says the frame it is in (`frame`, the count of
  those moves).

  It subscribes to the robot's odometry and its lasers (the RDF's
  sensors). On odometry the particles move by the motion since the last
  reading; a scan weighs them once the robot moved `update_distance` (m)
  or turned `update_angle` (rad) since the last weighing, using at most
  `beams` of its beams, evenly spread. A robot standing still is not
  weighed again, but its scan is still judged twice a second (below).

  **The map's unknown space.** A WDF's map is given whole: a beam ending
  in its unknown space is scored by its distance to the nearest
  obstacle, and one ending off the map as noise (a laser stops only at
  what the map holds). In a map being built they say nothing.

  **Lost and found.** Each scan is judged from the best particle (the
  mean of a cloud still split between places stands nowhere), two ways.
  A laser does not see through walls: beams that pass through a wall of
  the map well short of their end contradict the pose, while beams that
  end short of one (a box, a person the map does not hold) contradict
  nothing. And a scan should end on the map: the share of its beams that
  end within 0.25 m of an obstacle of the map (a beam without echo
  counting as a miss where the map has a wall in its range; a beam
  ending in unknown space, off the map or within 0.25 m of either, and
  not of a wall, not judged: the map does not know what stopped it) is
  set against what it usually is while tracking (learnt quickly
  upwards, slowly downwards, taken as at least 0.6). A scan is poor when
  more than `lost_through` of its judged beams contradict the pose, or
  when its share falls under `lost_hits` of the usual. Scans poor
  `lost_after` times more often than not (once a fresh cloud had ten
  weighings to settle) say the pose may be wrong, or that the map lacks
  what the laser sees (boxes, people, a map's open end). To tell which,
  the whole map is searched for the scan (the lattice scored with a
  wider sensor model, the best pose of each of up to 60 places refined,
  the best particle refined too). The robot is lost (carried away, or
  started from a wrong pose) only when a place more than 1 m from the
  best particle fits the scan better than the best place within 1 m by
  `lost_margin` (log-likelihood per beam with an echo), and the scan
  would not be poor from there, or when a place near fits better than
  the best particle by as much and places away fit about as well (a
  symmetric room: the moves to come tell them apart). Both need the
  tracked pose contradicted (more than `lost_through` of the beams
  through walls): a scan whose beams all end short of the map's walls is
  explained by boxes and people the map lacks as well as by a move. Then
  a place away is a move only if the next search, 0.3 m of travel later,
  finds it again where the odometry carried it (those places are sought
  again beside the lattice's). Otherwise nothing moves (the particles
  are only spread round the places near when these fit better by as
  much and the pose is contradicted), and the robot goes on 0.5 m
  before it searches again. A robot
  lost has its particles spread round the places found
  (`relocalizing`), and the scans after are weighed
  tempered (at most forty times, until the cloud gathers), so that
  places one scan cannot tell apart live on until the moves to come do.
  Scans poor again once the new cloud had its ten weighings search
  again. Particles that stay spread wider than 0.5 m for twenty
  weighings while the scans fit (and not while a search's places are
  weighed tempered) are searched for round the best particle only. Not
  in simultaneous localization and mapping (no map to start from): a map
  half built has not the places to search. An initial pose given
  roughly (`initial_sigma` wider than 0.15 m) is sought round itself at
  the first scan, within three of its standard deviations in position
  and heading. The fit of the scan (the mean per-beam likelihood over
  the best possible, in [0, 1]) gives the confidence.

  ## Published

      {:pose, robot, %{pose: {x, y, θ}, covariance: [[..], [..], [..]],
                      stamp: t, confidence: c, status: s}}

  (latest value, key `{:pose, robot}`) after each weighing and, between
  them, after odometry when `publish_period` (default 0.1 s) of stamp has
  passed. `confidence` in [0, 1] is the fit of the last scan, lowered as
  the position's standard deviation grows past 0.1 m. While the particles
  are spread wider than 0.3 m, `pose` is the mean of those within 1 m of
  the best one (the mean of a cloud split between two aisles stands in
  the rack between them); the covariance stays the whole cloud's. `status` is
  `:tracking`, `:uncertain` (a poor fit or a wide spread), `:lost`
  (about to search) or `:relocalizing`, or `:dead_reckoning` without a
  map. Also `{:particles, robot, %{poses: [{x, y, θ}], stamp: t}}`, up
  to 200 of them, at most twice a second.

  ## Parameters

    * `initial` - the start pose `{x, y, θ}`, `{x, y}` or a waypoint's name
      (default `{0, 0, 0}`), `initial_sigma` - `{σ_xy, σ_θ}` (default
      `{0.2, 0.1}`);
    * `particles` (default 500), `beams` (default 40 on a given map; in
      simultaneous localization and mapping, every beam), `seed` (default 1);
    * `sigma_hit`, `z_hit`, `z_rand` - the sensor model (defaults 0.1,
      0.5, 0.5; in simultaneous localization and mapping 0.05, 0.9,
      0.1). On a given map, as much noise as hits (nav2's example
      parameters too): beams ending on boxes the map lacks then pull
      the estimate less. Among eight boxes on turtlebot3_world
      (`mix tc.bench nav_unknown`, seed 3, run 4) the mean error fell
      from 0.082 m to 0.037 and the largest from 0.25 to 0.07, with
      0.9 and 0.1 before; `alphas` - the motion model (default from the RDF's
      `odometry_error`: generous multiples of its slips). A map being
      built is drawn at this module's own estimates: a scan weighed
      loosely fits, a few degrees off, the walls the scans before drew,
      and the heading follows the odometry's drift (a wheel 0.2 % larger
      than the other: 12 mrad a metre). Every beam, sharply weighed, holds
      it to the walls: on a generated building the heading drifted 2
      mrad a metre instead of 10, and the mean error over 900 s fell from
      0.46 m to 0.3;
    * `update_distance` (0.05 m), `update_angle` (0.05 rad),
      `publish_period` (0.1 s), `map_every` (2 s);
    * `calibrate` - in simultaneous localization and mapping, calibrate
      the odometry as it goes (default false): the heading corrections
      the scans make teach it the odometry's turn scale and turn per
      metre driven (a wheelbase off by 0.5 %, wheels of unequal size),
      which are then taken out of its moves
      (`ThinkingCap.Navigation.OdometryCalibration`). Off by default:
      on two generated buildings it did not map better (one run ended
      stuck at 19 % against 73 % without);
    * `slam_wall` - in simultaneous localization and mapping, the
      occupancy (0-100) from which a cell of the map being built counts as
      a wall (default 30: a wall seen once, from afar, is already one;
      beams that end near it would otherwise weigh less than beams that
      end in unknown space, and pull the estimate off);
    * `lost_through` (0.12), `lost_hits` (0.6), `lost_after` (3),
      `lost_margin` (0.3), `search_step` (0.2 m), `search_headings` (72).

  The params the filter reads as it runs (`beams`, `update_distance`,
  `update_angle`, `publish_period`, `map_every`, `slam_wall`, `lost_*`,
  `search_*`) are live parameters (`ThinkingCap.Module`): set while it
  runs, the next reading uses them. `initial`, `initial_sigma`,
  `particles`, `seed`, `sigma_hit`, `z_hit`, `z_rand` and `alphas` make
  the filter at start and are read-only.
  """

  use ThinkingCap.Module
  require Logger

  alias ThinkingCap.Config.WDF
  alias ThinkingCap.Navigation.{EKF, Maps, OccupancyGrid, OdometryCalibration, ParticleFilter}
  alias ThinkingCap.Navigation.Core.ModuleContext
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples
  alias ThinkingCap.Geometry
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @pair {:tuple, [:non_neg_number, :non_neg_number]}
  @params [
    initial:
      {{:or, [:point_or_pose, :place]},
       default: {0.0, 0.0, 0.0}, read_only: true, doc: "the start pose, or a waypoint's name"},
    initial_sigma:
      {@pair, default: {0.2, 0.1}, read_only: true, doc: "{σ_xy m, σ_θ rad} of the start pose"},
    particles: {{:int_range, 10, 100_000}, default: 500, read_only: true, doc: "particles"},
    beams:
      {{:int_range, 1, 4096},
       default: nil, doc: "beams of a scan weighed (40; in SLAM every beam)"},
    seed: {:integer, default: 1, read_only: true, doc: "random seed"},
    sigma_hit:
      {:pos_number, default: nil, read_only: true, doc: "sensor model σ, m (0.1; in SLAM 0.05)"},
    z_hit:
      {:probability,
       default: nil, read_only: true, doc: "sensor model: share of hits (0.5; in SLAM 0.9)"},
    z_rand:
      {:probability,
       default: nil, read_only: true, doc: "sensor model: share of noise (0.5; in SLAM 0.1)"},
    alphas:
      {{:tuple, List.duplicate(:non_neg_number, 4)},
       default: nil,
       read_only: true,
       doc: "motion model {α1..α4} (default from the RDF's odometry_error)"},
    update_distance: {:non_neg_number, default: 0.05, doc: "m moved between weighings"},
    update_angle: {:non_neg_number, default: 0.05, doc: "rad turned between weighings"},
    publish_period: {:pos_number, default: 0.1, doc: "s between estimates from odometry"},
    map_every: {:pos_number, default: 2.0, doc: "s between maps taken in SLAM"},
    slam_wall: {{:int_range, 1, 100}, default: 30, doc: "occupancy of a wall in SLAM"},
    calibrate:
      {:boolean,
       default: false, read_only: true, doc: "in SLAM, calibrate the odometry's systematic errors"},
    lost_through: {:probability, default: 0.12, doc: "share of beams through walls: poor"},
    lost_hits: {:probability, default: 0.6, doc: "share of the usual hits below which: poor"},
    lost_after: {:pos_integer, default: 3, doc: "poor scans before lost"},
    lost_margin:
      {:non_neg_number,
       default: 0.3, doc: "log-likelihood per beam a place far away must fit better by: lost"},
    search_step: {:pos_number, default: 0.2, doc: "m between poses of a map search"},
    search_headings: {{:int_range, 1, 720}, default: 72, doc: "headings of a map search"}
  ]
  @defaults ThinkingCap.Config.Schema.defaults(@params)

  @doc "The params this module takes (`c:ThinkingCap.Module.params/0`)."
  @impl true
  @spec params() :: keyword()
  def params, do: @params

  @doc """
  A live change of a param the filter reads as it runs (`beams`,
  `update_distance`, `update_angle`, `publish_period`, `map_every`,
  `slam_wall`, `lost_*`, `search_*`): the next reading uses it. Those
  that made the filter at start (`initial`, `particles`, `seed`, the
  sensor and motion models) are read-only.
  """
  @impl true
  def handle_param(key, value, state),
    do: {[], %{state | params: Keyword.put(state.params, key, value)}}

  # weighings a fresh cloud of particles gets before it may be judged lost
  @settling 10
  # m and rad within which a place found counts as the tracked one
  @near 1.0
  @near_turn 0.5
  # m the robot moves after a poor scan no other place explained before
  # another search
  @quiet 0.5
  # m the robot moves before a place away that fitted better is sought
  # again, within how many m of travel the second search must find it, and
  # within how many m of where the odometry carried it
  @recheck 0.3
  @suspect_for 3.0
  @same 0.5

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, Enum.to_list(params || []))
    rdf = ModuleContext.describe!(context, "laser localization")
    wdf = ModuleContext.read_wdf(context)
    lasers = for %{type: :laser} = s <- rdf.sensors, into: %{}, do: {s.name, s}

    if lasers == %{} do
      raise ArgumentError,
            "#{inspect(context.name)}: the robot of #{context.rdf} has no laser to localize with"
    end

    range_max = lasers |> Map.values() |> Enum.map(&elem(&1.range, 1)) |> Enum.max()
    odometry = Description.sensor_name(rdf, :odometry, :odom)
    initial = initial_pose(params[:initial], wdf)
    map = wdf_map(wdf)
    params = slam_defaults(params, map == nil)

    filter =
      ParticleFilter.new(initial, params[:initial_sigma],
        count: params[:particles],
        seed: params[:seed],
        sigma_hit: params[:sigma_hit],
        z_hit: params[:z_hit],
        z_rand: params[:z_rand],
        range_max: range_max,
        alphas: params[:alphas] || alphas(rdf.odometry_error)
      )

    filter =
      if map,
        do: ParticleFilter.set_map(filter, map, params[:seed], strict: true),
        else: filter

    state = %{
      robot: context.robot,
      params: params,
      lasers: lasers,
      odometry: odometry,
      filter: filter,
      source: if(filter.map, do: :wdf, else: nil),
      # no map to start from: the map is built at these estimates, and a
      # search of a map half built would move the robot somewhere wrong
      slam: filter.map == nil,
      map_at: nil,
      pending_map: nil,
      last_odometry: nil,
      odometry_at: nil,
      held: nil,
      moved: {0.0, 0.0},
      fit: nil,
      hits: nil,
      through: nil,
      baseline: nil,
      poor: 0,
      travelled: 0.0,
      quiet_until: nil,
      # places away a search found better while nothing contradicted the
      # pose: a move if the next search finds them again
      suspects: nil,
      updates: 0,
      spread: 0,
      checked: nil,
      status: if(filter.map, do: :tracking, else: :dead_reckoning),
      published: nil,
      particles_at: nil,
      frame: 0,
      # in SLAM: the odometry's systematic errors learned from the scans
      calibration: if(filter.map == nil and params[:calibrate], do: OdometryCalibration.new()),
      since: {0.0, 0.0}
    }

    # odometry first, then what else it hears, then the range sensors
    subscriptions =
      for template <-
            [
              Tuples.reading(odometry, context.robot),
              Tuples.map(context.robot),
              Tuples.map_correction(context.robot)
            ] ++
              for(sensor <- Map.keys(lasers), do: Tuples.reading(sensor, context.robot)),
          do: {:subscribe, template}

    {subscriptions, resume(state, Map.get(context, :handoff))}
  end

  # beams, sigma_hit, z_hit and z_rand not given: every beam, weighed
  # sharply, where the map is being built (see the moduledoc), else 40,
  # 0.1 and as much noise as hits
  defp slam_defaults(params, slam) do
    {beams, sigma, z_hit, z_rand} = if slam, do: {4096, 0.05, 0.9, 0.1}, else: {40, 0.1, 0.5, 0.5}

    params
    |> Keyword.update(:beams, beams, &(&1 || beams))
    |> Keyword.update(:sigma_hit, sigma, &(&1 || sigma))
    |> Keyword.update(:z_hit, z_hit, &(&1 || z_hit))
    |> Keyword.update(:z_rand, z_rand, &(&1 || z_rand))
  end

  @doc """
  What a standby needs to carry on (`c:ThinkingCap.Module.handoff/1`): the
  estimate and the odometry reading it is up to date with; the standby
  starts its particles round it.
  """
  @impl true
  @spec handoff(map()) :: map()
  def handoff(state) do
    {pose, covariance} = ParticleFilter.estimate(state.filter)
    %{pose: pose, covariance: covariance, last_odometry: state.last_odometry}
  end

  defp resume(state, %{pose: pose, covariance: [[sxx | _], [_, syy | _], [_, _, stt]]} = h) do
    sigma = {:math.sqrt(max(sxx, syy)) + 0.05, :math.sqrt(stt) + 0.02}
    filter = ParticleFilter.new(pose, sigma, particle_opts(state))

    filter =
      if state.filter.map,
        do:
          ParticleFilter.set_map(filter, state.filter.map, state.params[:seed],
            strict: state.filter.strict,
            threshold: if(state.slam, do: state.params[:slam_wall], else: 50)
          ),
        else: filter

    %{state | filter: filter, last_odometry: h.last_odometry}
  end

  defp resume(state, _handoff), do: state

  defp particle_opts(state) do
    {s, z_hit, z_rand, range_max} = state.filter.model

    [
      count: state.filter.count,
      seed: state.params[:seed],
      sigma_hit: s,
      z_hit: z_hit,
      z_rand: z_rand,
      range_max: range_max,
      alphas: state.filter.alphas
    ]
  end

  @impl true
  def handle_tuple(
        Tuples.reading(tag, robot, %{pose: {_, _, _} = odom} = p),
        %{odometry: tag, robot: robot} = s
      ) do
    stamp = Map.get(p, :stamp)

    case s.last_odometry do
      nil ->
        {[], %{s | last_odometry: odom, odometry_at: stamp}}

      previous ->
        {dx, dy, dth} = raw = EKF.relative(previous, odom)
        filter = ParticleFilter.move(s.filter, calibrated(s.calibration, raw))
        {turn, distance} = s.since
        since = {turn + dth, distance + OdometryCalibration.signed_distance(dx, dy)}
        s = %{s | since: since}
        {d, a} = s.moved
        step = :math.sqrt(dx * dx + dy * dy)
        moved = {d + step, a + abs(dth)}

        s = %{
          s
          | filter: filter,
            last_odometry: odom,
            odometry_at: stamp,
            moved: moved,
            travelled: s.travelled + step
        }

        {actions, s} = if due?(s, stamp), do: publish(s, stamp), else: {[], s}
        {more, s} = release_held(s)
        {actions ++ more, s}
    end
  end

  # the map builder's map, when there is no WDF map to hold to: a map being
  # built knows little at first, and what it does not know says nothing
  def handle_tuple(
        Tuples.map(robot, %OccupancyGrid{} = map),
        %{robot: robot, slam: true} = state
      ),
      do: {[], %{state | pending_map: map}}

  # the map builder closed a loop: its map's frame moved under the robot;
  # the particles move with it, onto the map drawn in the new frame
  def handle_tuple(
        Tuples.map_correction(robot, %{
          from: from,
          to: to,
          frame: frame,
          map: %OccupancyGrid{} = map
        }),
        %{robot: robot, slam: true} = state
      )
      when frame > state.frame do
    filter =
      state.filter
      |> ParticleFilter.transform(from, to)
      |> ParticleFilter.set_map(map, state.params[:seed], threshold: state.params[:slam_wall])

    {[],
     %{
       state
       | filter: filter,
         frame: frame,
         source: :sensed,
         status: if(state.status == :dead_reckoning, do: :tracking, else: state.status),
         pending_map: nil,
         map_at: state.published || state.map_at
     }}
  end

  def handle_tuple(Tuples.reading(tag, robot, %{ranges: ranges} = scan), %{robot: robot} = state)
      when is_map_key(state.lasers, tag) and is_list(ranges) do
    if ahead?(Map.get(scan, :stamp), state.odometry_at) do
      # taken after the odometry so far: weighed once the odometry of its
      # time has moved the particles there (a scan held before is weighed
      # now, with the odometry there is)
      {actions, state} = release_held(%{state | held: nil}, state.held)
      {actions, %{state | held: {tag, scan}}}
    else
      scan(state, tag, scan)
    end
  end

  def handle_tuple(_tuple, state), do: {[], state}

  defp ahead?(stamp, odometry_at),
    do: is_number(stamp) and is_number(odometry_at) and stamp > odometry_at + 1.0e-9

  defp release_held(%{held: held} = state), do: release_held(state, held)

  defp release_held(state, nil), do: {[], state}

  defp release_held(state, {tag, scan} = held) do
    if ahead?(Map.get(scan, :stamp), state.odometry_at) and state.held == held,
      do: {[], state},
      else: scan(%{state | held: nil}, tag, scan)
  end

  defp scan(state, tag, scan) do
    stamp = Map.get(scan, :stamp)
    state = take_map(state, stamp)
    {d, a} = state.moved

    if d >= state.params[:update_distance] or a >= state.params[:update_angle] or
         state.fit == nil do
      laser = Map.fetch!(state.lasers, tag)
      beams = beams(scan, laser, state.params[:beams])
      many = fn -> beams(scan, laser, 3 * state.params[:beams]) end

      state
      |> first_fix(many)
      |> learning(&weigh(&1, beams, many))
      |> Map.merge(%{moved: {0.0, 0.0}, checked: stamp})
      |> publish(stamp)
    else
      # standing still: no weighing (the same scan again would only make the
      # particles surer), but still a look whether the scan fits
      if stamp && (state.checked == nil or stamp - state.checked >= 0.5) do
        laser = Map.fetch!(state.lasers, tag)
        beams = beams(scan, laser, state.params[:beams])
        many = fn -> beams(scan, laser, 3 * state.params[:beams]) end
        state |> judge(beams, many) |> Map.put(:checked, stamp) |> publish(stamp)
      else
        {[], state}
      end
    end
  end

  ## the filter

  defp calibrated(nil, move), do: move
  defp calibrated(calibration, move), do: OdometryCalibration.apply_to(calibration, move)

  # a weighing, and the heading correction it made taught to the odometry
  # calibration (while tracking; a search's jump teaches nothing)
  defp learning(%{calibration: nil} = state, weigh), do: weigh.(state)

  defp learning(state, weigh) do
    {{_, _, before}, _} = ParticleFilter.estimate(state.filter)
    tracking = state.status == :tracking and state.filter.map != nil
    state = weigh.(state)
    {{_, _, now}, _} = ParticleFilter.estimate(state.filter)
    delta = normalize_angle(now - before)
    {turn, distance} = state.since
    c = state.calibration

    calibration =
      if tracking and state.status == :tracking and abs(delta) < 0.1,
        do: OdometryCalibration.learn(c, turn, distance, delta + c.a * turn + c.b * distance),
        else: c

    %{state | calibration: calibration, since: {0.0, 0.0}}
  end

  # the map builder's map, at most every map_every seconds
  defp take_map(%{pending_map: nil} = state, _stamp), do: state

  defp take_map(%{pending_map: map} = state, stamp) do
    if state.map_at == nil or stamp == nil or stamp - state.map_at >= state.params[:map_every] do
      filter =
        ParticleFilter.set_map(state.filter, map, state.params[:seed],
          threshold: state.params[:slam_wall]
        )

      status = if state.status == :dead_reckoning, do: :tracking, else: state.status
      %{state | filter: filter, source: :sensed, map_at: stamp, pending_map: nil, status: status}
    else
      state
    end
  end

  # an initial pose known only roughly: the scan sought round it first
  defp first_fix(%{fit: nil, filter: %{map: %OccupancyGrid{}}} = state, many) do
    {s_xy, s_th} = state.params[:initial_sigma]

    if s_xy > 0.15 do
      {{x, y, th}, _} = ParticleFilter.estimate(state.filter)
      radius = min(3 * s_xy, 3.0)

      # the heading as roughly as it was given: a scan in a symmetric place
      # fits as well turned round
      {filter, _found} =
        ParticleFilter.relocalize(state.filter, many.(),
          around: {{x, y}, radius, {th, min(3 * s_th, :math.pi())}},
          step: state.params[:search_step] / 2,
          headings: state.params[:search_headings],
          seed: state.params[:seed]
        )

      %{state | filter: filter}
    else
      state
    end
  end

  defp first_fix(state, _many), do: state

  defp weigh(%{filter: %{map: nil}} = state, _beams, _many), do: state

  # `many`: more of the scan's beams, for a search of the whole map
  defp weigh(state, beams, many) do
    # after a search, hypotheses the scan cannot tell apart live on until
    # the moves to come do
    temper = if state.status == :relocalizing and state.updates <= 40, do: 0.25, else: 1.0
    {filter, _mean} = ParticleFilter.sense(state.filter, beams, temper)
    judge(%{state | filter: filter, updates: state.updates + 1}, beams, many)
  end

  # judged from the best particle (the mean of a cloud still split between
  # places fits nowhere), and not while a fresh cloud settles
  defp judge(%{filter: %{map: nil}} = state, _beams, _many), do: state

  defp judge(%{filter: filter} = state, beams, many) do
    best = ParticleFilter.best(filter)

    case {ParticleFilter.fit(filter, beams, best),
          ParticleFilter.contradiction(filter, beams, best)} do
      {nil, _} ->
        state

      {{fit, _known}, contradiction} ->
        # beams seen through walls say the pose is wrong, and so do beams
        # ending far from what the map holds, many more than usual; a good
        # scan now and then takes one poor one back, not all of them
        hits = ParticleFilter.hits(filter, beams, best)
        misfit = misfit?(state, hits)

        poor =
          if through?(state, contradiction) or misfit,
            do: state.poor + 1,
            else: max(state.poor - 1, 0)

        state = %{
          state
          | hits: hits,
            through: contradiction,
            baseline: baseline(state, hits, misfit)
        }

        # a cloud that stays spread wide has no place either
        {_pose, [[sxx | _], [_, syy | _] | _]} = ParticleFilter.estimate(filter)
        spread = if :math.sqrt(max(sxx, syy)) > 0.5, do: state.spread + 1, else: 0
        state = %{state | fit: fit, poor: poor, spread: spread}

        cond do
          state.slam or state.updates <= @settling ->
            settle(state)

          poor >= state.params[:lost_after] and quiet?(state) ->
            settle(%{state | poor: 0})

          poor >= state.params[:lost_after] ->
            confirm(state, many.())

          spread >= 2 * @settling and searched?(state) ->
            relocalize(state, many.(), around(state))

          true ->
            settle(state)
        end
    end
  end

  # more than lost_through of the judged beams seen through walls
  defp through?(state, {share, judged}), do: judged >= 10 and share > state.params[:lost_through]
  defp through?(_state, nil), do: false

  # a scan poor from `pose`, judged as from the tracked one
  defp poor_at?(state, beams, {_ll, x, y, th}) do
    pose = {x, y, th}

    through?(state, ParticleFilter.contradiction(state.filter, beams, pose)) or
      misfit?(state, ParticleFilter.hits(state.filter, beams, pose))
  end

  # a scan whose beams end on the map far less often than they did while
  # tracking (by the best particle)
  defp misfit?(_state, nil), do: false
  defp misfit?(_state, {_share, judged}) when judged < 10, do: false

  defp misfit?(state, {share, _judged}),
    do: share < state.params[:lost_hits] * max(state.baseline || 1.0, 0.6)

  # what share of the beams end on the map while tracking, from the scans
  # that fit: learnt quickly upwards, slowly downwards (a wrong pose that
  # still passes must not teach it to expect little)
  defp baseline(%{status: :tracking, baseline: b}, {share, judged}, false) when judged >= 10 do
    cond do
      b == nil -> share
      share > b -> b + 0.1 * (share - b)
      true -> b + 0.01 * (share - b)
    end
  end

  defp baseline(state, _hits, _misfit), do: state.baseline

  # a cloud split between the places a search found is left to the moves
  # to come while it is weighed tempered
  defp searched?(state), do: state.status != :relocalizing or state.updates > 40

  # a cloud spread wide while the scan fits: the places round its best
  # particle (a scan that fits says the robot was not carried away)
  defp around(state) do
    {x, y, th} = ParticleFilter.best(state.filter)
    {_, [[sxx | _], [_, syy | _], [_, _, stt]]} = ParticleFilter.estimate(state.filter)
    radius = min(max(3 * :math.sqrt(max(sxx, syy)), 1.0), 3.0)
    {{x, y}, radius, {th, min(3 * :math.sqrt(max(stt, 0.0)) + 0.2, :math.pi())}}
  end

  # a scan found poor again soon after one that fitted no other place
  # better: left alone until the robot moved on
  defp quiet?(%{quiet_until: nil}), do: false
  defp quiet?(state), do: state.travelled < state.quiet_until

  # poor scans say the pose may be wrong, or that the map lacks what the
  # laser sees (boxes, people, racks moved): the whole map is searched,
  # and the robot is lost only when a place away from the tracked one fits
  # the scan clearly better (by lost_margin per beam) than the best place
  # near it; otherwise the scan is left unexplained, and the particles are
  # spread round the best place near the tracked one when it fits clearly
  # better than the tracked pose itself
  defp confirm(%{filter: filter} = state, beams) do
    best = ParticleFilter.best(filter)
    used = max(ParticleFilter.echoes(filter, beams), 1)

    # the places away the last search found, where the odometry carried
    # them, are sought again beside the lattice's
    carried = carried(state)

    found =
      ParticleFilter.search(filter, beams,
        step: state.params[:search_step],
        headings: state.params[:search_headings],
        from: best,
        also: carried
      )

    {near, far} = Enum.split_with(found, &near?(&1, best))
    margin = state.params[:lost_margin] * used
    here = ParticleFilter.score(filter, beams, best)
    local = List.first(near, {here, best})
    # a place away fits only if its scan would not be poor itself: with
    # few echoes (a robot by the map's open end, boxes round it) some
    # place fits them, whose walls the beams without echo pass through
    far = Enum.reject(far, &poor_at?(state, beams, &1))

    local_ll = elem(local, 0)
    # places away that fit about as well as the best near one
    alike = Enum.filter(far, fn {ll, _, _, _} -> ll >= local_ll - margin end)

    # the places away that fit clearly better than the best near one
    better = Enum.filter(far, fn {ll, _, _, _} -> ll - local_ll > margin end)

    cond do
      better != [] and (contradicted?(state) or seen_before?(carried, better)) ->
        lost(state, Enum.sort_by(near ++ far, &(-elem(&1, 0))), gain(far, local, used), best)

      better != [] ->
        # nothing the laser sees contradicts the tracked pose (its beams
        # end short of the map's walls: boxes, people, or a move): a
        # move only if a search after the robot moved on finds the
        # same place away again
        Logger.info(
          "#{inspect(state.robot)}: a place away fits the scan better at #{place(best)} " <>
            "(#{describe_fit(state)}; by #{gain(far, local, used)} per beam), but nothing " <>
            "seen contradicts the pose: searching again after #{@recheck} m"
        )

        suspects = %{odometry: state.last_odometry, places: better, at: state.travelled}
        settle(%{state | poor: 0, quiet_until: state.travelled + @recheck, suspects: suspects})

      local_ll - here > margin and alike != [] and contradicted?(state) ->
        # the tracked pose is wrong, and the scan fits places near and
        # away alike (a symmetric room, or boxes the map lacks): the
        # moves to come tell them apart. A robot is seldom carried away,
        # so the near places are preferred by the margin a place away
        # must win by: the estimate stays near, and a few particles wait
        # at the places away in case it was
        near = Enum.map(near, fn {ll, x, y, th} -> {ll + margin, x, y, th} end)
        lost(state, Enum.sort_by(near ++ alike, &(-elem(&1, 0))), gain(far, local, used), best)

      true ->
        Logger.info(
          "#{inspect(state.robot)}: the scan fits the map poorly at #{place(best)} " <>
            "(#{describe_fit(state)}) " <>
            "but no place away fits it better (#{gain(far, local, used)} per beam): " <>
            "the map lacks what the laser sees"
        )

        state = %{state | poor: 0, quiet_until: state.travelled + @quiet}

        # a near place that fits better while nothing contradicts the
        # tracked pose is most likely the boxes' doing: the weighings to
        # come are left to it
        if local_ll - here > margin and contradicted?(state) do
          {filter, _} = ParticleFilter.relocalize_to(filter, near, seed: state.params[:seed])
          settle(%{state | filter: filter, updates: 0})
        else
          settle(state)
        end
    end
  end

  # the tracked pose contradicted: more than lost_through of the beams
  # judged pass through walls of the map
  defp contradicted?(state), do: through?(state, state.through)

  # the places away the last search found (within @suspect_for m of
  # travel), carried by the odometry since
  defp carried(%{suspects: nil}), do: []

  defp carried(%{suspects: suspects} = state) do
    if state.travelled - suspects.at <= @suspect_for do
      delta = Geometry.relative(suspects.odometry, state.last_odometry)
      for {_, x, y, th} <- suspects.places, do: Geometry.compose({x, y, th}, delta)
    else
      []
    end
  end

  # a place of `found` where a place the last search found away is now
  defp seen_before?(carried, found),
    do: Enum.any?(carried, fn pose -> Enum.any?(found, &near?(&1, pose, @same, @near_turn)) end)

  # near the tracked pose: a small correction of it, in place and heading
  # (the same place turned round is another hypothesis: in a symmetric
  # map, the twin place a half turn away fits as well)
  defp near?(candidate, pose, within \\ @near, turn \\ @near_turn)

  defp near?({_, x, y, th}, {bx, by, bth}, within, turn),
    do:
      (x - bx) ** 2 + (y - by) ** 2 <= within * within and
        abs(normalize_angle(th - bth)) <= turn

  defp gain([], _local, _used), do: "-"
  defp gain([c | _], local, used), do: gain(elem(c, 0), local, used)

  defp gain(ll, {local, _, _, _}, used),
    do: :erlang.float_to_binary((ll - local) / used, decimals: 2)

  defp gain(ll, {local, _pose}, used), do: gain(ll, {local, 0, 0, 0}, used)

  defp lost(state, found, gain, from) do
    Logger.info(
      "#{inspect(state.robot)}: lost at #{place(from)} " <>
        "(the scan fits the map poorly: #{describe_fit(state)}; " <>
        "a place away fits it better by #{gain} per beam)"
    )

    {filter, best} = ParticleFilter.relocalize_to(state.filter, found, seed: state.params[:seed])
    if best, do: Logger.info("#{inspect(state.robot)}: best fit at #{place(best)}")

    %{
      state
      | filter: filter,
        poor: 0,
        spread: 0,
        status: :relocalizing,
        updates: 0,
        quiet_until: nil,
        suspects: nil
    }
  end

  # the whole map, or the places `around` the estimate (the estimate
  # staying a candidate): a robot carried away, a wrong initial pose
  defp relocalize(state, beams, around) do
    Logger.info(
      "#{inspect(state.robot)}: lost (the scan fits the map poorly: #{describe_fit(state)}); " <>
        "searching #{if around, do: "round the estimate", else: "the map"}"
    )

    {filter, found} =
      ParticleFilter.relocalize(state.filter, beams,
        step: state.params[:search_step],
        headings: state.params[:search_headings],
        seed: state.params[:seed],
        around: around
      )

    if found, do: Logger.info("#{inspect(state.robot)}: best fit at #{inspect(found)}")
    %{state | filter: filter, poor: 0, spread: 0, status: :relocalizing, updates: 0}
  end

  defp place({x, y, th}) do
    "{#{Enum.map_join([x, y, th], ", ", &:erlang.float_to_binary(&1 * 1.0, decimals: 2))}}"
  end

  defp describe_fit(state) do
    hits =
      case state.hits do
        {share, judged} -> "#{round(share * 100)}% of #{judged} beams on the map"
        nil -> "no beam on the map"
      end

    usual = if state.baseline, do: ", usually #{round(state.baseline * 100)}%", else: ""

    through =
      case state.through do
        {share, judged} -> ", #{round(share * 100)}% of #{judged} through walls"
        nil -> ""
      end

    "#{hits}#{usual}#{through}, spread #{state.spread}"
  end

  defp settle(state) do
    {_pose, [[sxx | _], [_, syy | _] | _]} = ParticleFilter.estimate(state.filter)
    sigma = :math.sqrt(max(sxx, syy))

    status =
      cond do
        state.poor > 0 -> if state.status == :relocalizing, do: :relocalizing, else: :uncertain
        sigma > 0.3 -> if state.status == :relocalizing, do: :relocalizing, else: :uncertain
        true -> :tracking
      end

    %{state | status: status}
  end

  # about `n` beams, evenly spread: {x, y, angle, range} in the robot
  # frame; a beam without echo (reading the scan's range_max) gets a range
  # beyond any laser's, 1.0e6: weighing skips it, judging asks whether the
  # map has a wall in its way
  defp beams(scan, laser, n) do
    {px, py, pth} = Map.get(laser, :pose, {0.0, 0.0, 0.0})
    range_min = Map.get(scan, :range_min, 0.0)
    range_max = scan.range_max
    total = length(scan.ranges)
    every = max(1, div(total, n))

    scan.ranges
    |> Enum.with_index()
    |> Enum.filter(fn {r, i} -> rem(i, every) == 0 and is_number(r) and r >= range_min end)
    |> Enum.map(fn {r, i} ->
      a = pth + scan.angle_min + i * scan.angle_increment
      r = if r < range_max, do: r, else: 1.0e6

      <<px * 1.0::float-native, py * 1.0::float-native, a * 1.0::float-native,
        r * 1.0::float-native>>
    end)
    |> IO.iodata_to_binary()
  end

  ## publishing

  defp due?(%{published: nil}, _stamp), do: true
  defp due?(_state, nil), do: true
  defp due?(state, stamp), do: stamp - state.published >= state.params[:publish_period] - 1.0e-9

  # the pose published: the cloud's mean while it is gathered, its
  # likeliest place while it is split between places (the mean of two
  # aisles stands in the rack between them); the covariance is the whole
  # cloud's, so that a split cloud says how unsure it is
  defp publish(state, stamp) do
    {pose, covariance} = ParticleFilter.estimate(state.filter)
    [[sxx | _], [_, syy | _] | _] = covariance
    sigma = :math.sqrt(max(max(sxx, syy), 0.0))
    pose = if sigma > 0.3, do: elem(ParticleFilter.mode(state.filter, 1.0), 0), else: pose
    confidence = (state.fit || 0.0) * min(1.0, 0.1 / max(sigma, 0.1))

    payload = %{
      pose: pose,
      covariance: covariance,
      stamp: stamp,
      confidence: Float.round(confidence, 3),
      status: state.status,
      frame: state.frame
    }

    out = [out: Tuples.keyed(Tuples.pose(state.robot, payload))]
    {more, state} = particles(state, stamp)
    last = if is_number(stamp), do: stamp, else: state.published
    {out ++ more, %{state | published: last}}
  end

  defp particles(state, stamp) do
    if is_number(stamp) and (state.particles_at == nil or stamp - state.particles_at >= 0.5) do
      poses = ParticleFilter.sample(state.filter, 200)
      tuple = Tuples.particles(state.robot, %{poses: poses, stamp: stamp})
      {[out: Tuples.keyed(tuple)], %{state | particles_at: stamp}}
    else
      {[], state}
    end
  end

  ## descriptions

  # generous multiples of the RDF's slips (the filter must cover what the
  # error model does not say: wheels on a bump, a floor's slope)
  defp alphas(error) do
    slip = max(Map.get(error || %{}, :slip, 0.01) || 0.01, 0.01)
    turn = max(Map.get(error || %{}, :turn_slip, 0.02) || 0.02, 0.02)
    {min(0.5, 25 * turn * turn + 0.02), 0.01, min(0.5, 25 * slip * slip + 0.005), 0.005}
  end

  defp wdf_map(nil), do: nil

  defp wdf_map(%WDF{} = wdf) do
    if WDF.empty?(wdf) do
      nil
    else
      opts = if wdf.grid, do: [unknown: :free], else: [resolution: 0.05]
      Maps.prior(wdf, Maps.grid_from_wdf(wdf, opts)) |> known_inside(wdf)
    end
  end

  # a WDF drawn with walls only knows nothing of the floor: the cells
  # inside its walls' bounds count as free space
  defp known_inside(map, %WDF{grid: nil}) do
    data =
      for <<v::signed-8 <- map.data>>, into: <<>>, do: <<if(v < 0, do: 0, else: v)::signed-8>>

    %{map | data: data}
  end

  defp known_inside(map, _wdf), do: map

  defp initial_pose({x, y, th}, _wdf), do: {x * 1.0, y * 1.0, th * 1.0}
  defp initial_pose({x, y}, _wdf), do: {x * 1.0, y * 1.0, 0.0}

  defp initial_pose(name, wdf) when is_atom(name) do
    waypoints = if wdf, do: wdf.waypoints, else: []

    case Enum.find(waypoints, &(&1.name == name)) do
      nil ->
        raise ArgumentError,
              "localization: initial: #{inspect(name)} is not a waypoint of the world " <>
                "(waypoints: #{Enum.map_join(waypoints, ", ", &inspect(&1.name))})"

      %{at: at} ->
        initial_pose(at, wdf)
    end
  end
end
