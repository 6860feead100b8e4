defmodule ThinkingCap.Navigation.Mapper do
  @moduledoc """
  Map building as an ADF module (event-driven): fuses the robot's lasers
  and sonar rings into a fuzzy grid map (`ThinkingCap.Navigation.Maps.SensedGrid`)
  at the robot's estimated pose, and publishes what it knows.

      mapper: [module: ThinkingCap.Navigation.Mapper, activity: :event]

  **With a WDF** the map covers the world's grid
  (`ThinkingCap.Navigation.Maps.grid_from_wdf/2`) and starts from it: the
  walls, obstacles and closed doors it draws are believed occupied, the
  free cells of its imported `map_server` map believed empty (degree
  `prior`), and what the sensors see corrects them (a moved pallet, a shut
  door, a box nobody drew). **Without one** (no WDF, or one with no walls,
  obstacles or map) it starts from nothing: a map of `size` metres centred
  on the start pose.

  It subscribes to the robot's range sensors (every `:laser` and `:sonar`
  of its RDF), its odometry (the RDF's odometry sensor) and its estimated
  pose `{:pose, robot, %{pose: _, stamp: _}}`. A reading is placed at the
  estimate moved on by the odometry between the estimate's stamp and the
  reading's, so that a scan taken while turning lands where it was taken.
  Readings before the first estimate wait for none: they are dropped.
  With each reading, the ground under the robot's footprint (the RDF's)
  is marked empty: the robot stands there.

  ## Published (latest values)

    * `{:map, robot, %ThinkingCap.Navigation.OccupancyGrid{}}` (key
      `{:map, robot}`), the observed part of the map, at most every
      `publish_every` seconds of sensor time and only when it changed;
      cells are `round(100 · (O ∧ ¬E))`, −1 unknown; `version` counts the
      publications;
    * `{:topology, robot, %ThinkingCap.Navigation.Topology{}}` (key
      `{:topology, robot}`), its rooms, corridors and doors
      (`ThinkingCap.Navigation.Maps.Rooms`, names kept as the map grows),
      every `topology_every` seconds;
    * `{:segments, robot, %{segments: [{{x1, y1}, {x2, y2}, degree}], stamp: t}}`
      (key `{:segments, robot}`), the walls as fuzzy segments: each
      fitted to the obstacle cells that border free space, with the mean
      occupancy of its cells as its degree, with the topology;
    * `{:map_saved, robot, %{path: p, result: :ok | {:error, reason}}}`
      after a save.

  ## Saving

  With `save: "path.yaml"` the map is saved in the `map_server` format
  (`ThinkingCap.Navigation.OccupancyGrid.save/2`, drawn crisp by
  `ThinkingCap.Navigation.OccupancyGrid.crisp/1`; its directory made if
  missing) every `save_every` seconds and when the module stops. A
  `{:save_map, robot, %{path: p}}` tuple saves it at once to `p`.

  ## Parameters

    * `resolution` - cell size, m (default 0.05; with a WDF map, the map's);
    * `size` - `{width, height}` m of a map started from nothing (default
      `{60, 60}`);
    * `initial` - where a map started from nothing is centred: `{x, y}`
      or `{x, y, θ}` (default `{0, 0}`);
    * `prior` - the degree given to the WDF's cells (default 0.7);
    * `publish_every` (default 1.0 s), `topology_every` (default 5.0 s);
    * `save`, `save_every` (default 30 s);
    * `max_turn_rate` - scans taken while the robot turns faster (rad/s,
      default 0.6; nil: every scan) are left out: they land smeared;
    * `fade`, `lambda`, `known`, `laser`, `sonar` - the fuzzy grid's
      (`ThinkingCap.Navigation.Maps.SensedGrid.new/3`); on a robot with
      a laser, sonars add only echoes closer than 1 m, weakly, by default
      (`sonar: [k_empty: 0.0, k_occupied: 0.1, trust: 1.0]`): their wide
      cones and specular walls would empty walls the laser sees, and their
      arcs round a pillar stay where the laser cannot clear them (in its
      shadow);
    * `door_width`, `min_area` - the room segmentation's
      (`ThinkingCap.Navigation.Maps.Rooms.from_occupancy/2`);
    * `loop_closure` - in a map started from nothing, close loops
      (default true; see below);
    * `slam` - the loop closure's options, numbers
      (`ThinkingCap.Navigation.Maps.Loops.new/1`, with those of
      `ThinkingCap.Navigation.Maps.PoseGraph.new/1`; default none).

  ## Loop closure

  A map built from nothing at the laser localizer's estimates
  (`ThinkingCap.Navigation.MCL` in SLAM) drifts with the odometry's slips:
  walls seen twice land twice, doors close up. With `loop_closure` the
  map builder keeps its laser scans and a pose graph of where they were
  taken (`ThinkingCap.Navigation.Maps.Loops`,
  `ThinkingCap.Navigation.Maps.PoseGraph`); when the robot comes back
  where it was and its scan matches the old ones sharply, the graph is
  optimized and the map drawn again from the scans at their corrected
  poses (sonar readings are not kept: they are not drawn again). The
  graph's chain of scan matches drifts less than the localizer: when it
  parts from the localizer's estimate by 5 cm or 0.015 rad, the map is
  drawn again at the graph's poses too (`Loops.new/1`'s `follow_distance`,
  `follow_angle`). It then publishes, with the new map,

    * `{:map_correction, robot, %{from: pose, to: pose, frame: n, map: map, stamp: t}}`
      (key `{:map_correction, robot}`): the map's frame moved so that
      the robot's pose `from` is now `to`; the localizer carries its
      estimate along and takes the new map at once. Its estimates say
      which frame they are in (`frame` in `{:pose, robot, _}`): one of
      the frame before is carried along here too.

  A localizer whose estimates carry no `frame` (beacons, a known world)
  holds the map to its own frame: then no loops are closed.

  A robot with no range sensor cannot build a map: `init/2` refuses it
  with an error naming the RDF.
  """

  use ThinkingCap.Module
  require Logger

  alias ThinkingCap.Config.WDF
  alias ThinkingCap.Navigation.{EKF, Maps, OccupancyGrid}
  alias ThinkingCap.Navigation.Core.ModuleContext
  alias ThinkingCap.Navigation.Maps.{Loops, Rooms, SensedGrid, Segments}
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @pair {:tuple, [:pos_number, :pos_number]}
  @degrees {:keyword_of, :non_neg_number}
  @params [
    resolution: {:pos_number, default: 0.05, doc: "cell size, m (with a WDF map: the map's)"},
    size: {@pair, default: {60.0, 60.0}, doc: "{width, height} m of a map started from nothing"},
    initial: {:point_or_pose, default: {0.0, 0.0}, doc: "where that map is centred"},
    prior: {:probability, default: 0.7, doc: "degree given to the WDF's cells"},
    publish_every: {:pos_number, default: 1.0, doc: "s between maps published"},
    topology_every: {:pos_number, default: 5.0, doc: "s between topologies published"},
    save: {:string, default: nil, doc: "where to save the map (map_server YAML)"},
    save_every: {:pos_number, default: 30.0, doc: "s between saves"},
    door_width: {:pos_number, default: 1.2, doc: "widest gap taken for a door, m"},
    min_area: {:pos_number, default: 1.5, doc: "smallest room, m²"},
    max_turn_rate:
      {{:or, [:non_neg_number, {:one_of, [nil]}]},
       default: 0.6, doc: "rad/s: scans taken turning faster are left out (nil: none)"},
    fade: {:probability, default: nil, doc: "the fuzzy grid's fade (SensedGrid)"},
    lambda: {{:tuple, [:probability, :probability]}, default: nil, doc: "fading {λe, λo}"},
    known: {:probability, default: nil, doc: "degree below which a cell is unknown"},
    laser: {@degrees, default: nil, doc: "laser degrees: k_empty, k_occupied, range"},
    sonar: {@degrees, default: nil, doc: "sonar degrees: k_empty, k_occupied, trust"},
    loop_closure:
      {:boolean, default: true, doc: "close loops in a map built from nothing (pose-graph SLAM)"},
    slam:
      {@degrees, default: [], doc: "the loop closure's options (Loops.new/1 and PoseGraph.new/1)"}
  ]
  @defaults ThinkingCap.Config.Schema.defaults(@params)

  @doc "The params this module takes (`c:ThinkingCap.Module.params/0`)."
  @impl true
  @spec params() :: keyword()
  def params, do: @params

  @grid_opts [:fade, :lambda, :known, :laser, :sonar]
  # odometry readings kept to place readings between estimates
  @history 64

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, Enum.to_list(params || []))
    rdf = ModuleContext.describe!(context, "the map builder")
    sensors = range_sensors(rdf)

    if sensors == %{} do
      raise ArgumentError,
            "#{inspect(context.name)}: the robot of #{context.rdf} has no laser or sonar: " <>
              "there is nothing to build a map from"
    end

    odometry = Description.sensor_name(rdf, :odometry, :odom)
    params = Keyword.put(params, :sonar, sonar_degrees(sensors, params))
    footprint = Description.circles(rdf.footprint)
    {grid, blank} = new_grid(ModuleContext.read_wdf(context), params)
    lasers = for {tag, %{type: :laser, pose: mount}} <- sensors, into: %{}, do: {tag, mount}

    state = %{
      robot: context.robot,
      params: params,
      sensors: sensors,
      footprint: footprint,
      odometry: odometry,
      grid: grid,
      history: :queue.new(),
      estimate: nil,
      stamp: nil,
      changed: false,
      version: 0,
      published: nil,
      topology: nil,
      topology_at: nil,
      saved_at: nil,
      last_map: nil,
      lasers: lasers,
      loops:
        if(blank and params[:loop_closure] and lasers != %{},
          do: Loops.new(Enum.to_list(params[:slam]))
        )
    }

    # odometry first, then what else it hears, then the range sensors
    subscriptions =
      for template <-
            [
              Tuples.reading(odometry, context.robot),
              Tuples.pose(context.robot),
              Tuples.save_map(context.robot)
            ] ++
              for(sensor <- Map.keys(sensors), do: Tuples.reading(sensor, context.robot)),
          do: {:subscribe, template}

    {subscriptions, resume(state, Map.get(context, :handoff))}
  end

  @doc """
  What a standby needs to carry on (`c:ThinkingCap.Module.handoff/1`): the
  last published map, which seeds the standby's grid.
  """
  @impl true
  @spec handoff(map()) :: map()
  def handoff(state), do: %{map: state.last_map, version: state.version}

  defp resume(state, %{map: %OccupancyGrid{} = map, version: version}) do
    grid = SensedGrid.seeded(map, state.params[:prior], grid_opts(state.params))
    %{state | grid: grid, version: version, last_map: map}
  end

  defp resume(state, _handoff), do: state

  @impl true
  def handle_tuple(
        Tuples.reading(tag, robot, %{pose: pose, stamp: t}),
        %{robot: robot, odometry: tag} = state
      )
      when is_number(t) do
    history = :queue.in({t, pose}, state.history)
    history = if :queue.len(history) > @history, do: :queue.drop(history), else: history
    {[], %{state | history: history}}
  end

  def handle_tuple(Tuples.pose(robot, %{pose: {_, _, _} = pose} = p), %{robot: robot} = state) do
    stamp = Map.get(p, :stamp)
    # a localizer that does not follow the map's frame (beacons, an EKF on
    # a known world) holds the map to itself: no loops to close
    state = if Map.has_key?(p, :frame), do: state, else: %{state | loops: nil}

    case in_frame(state, pose, Map.get(p, :frame, 0)) do
      nil -> {[], state}
      pose -> {[], %{state | estimate: {pose, odometry_at(state, stamp)}}}
    end
  end

  def handle_tuple(Tuples.save_map(robot, %{path: path}), %{robot: robot} = state)
      when is_binary(path),
      do: save(state, path)

  def handle_tuple(
        Tuples.reading(tag, robot, %{ranges: ranges} = reading),
        %{robot: robot} = state
      )
      when is_map_key(state.sensors, tag) and is_list(ranges) do
    pose = pose_at(state, Map.get(reading, :stamp))

    cond do
      pose == nil ->
        {[], state}

      # a scan taken while turning fast lands smeared (the pose a sweep was
      # taken at is known less well than the sweep is long): left out
      turning_fast?(state) ->
        {[], state}

      true ->
        add(state.grid, Map.fetch!(state.sensors, tag), reading, pose)
        SensedGrid.add_footprint(state.grid, pose, state.footprint)
        stamp = Map.get(reading, :stamp) || state.stamp
        state = %{state | changed: true, stamp: stamp}

        case record(state, tag, reading, pose) do
          {:closed, from, to, state} -> redraw(state, from, to)
          {:none, state} -> due(state)
        end
    end
  end

  def handle_tuple(_tuple, state), do: {[], state}

  defp turning_fast?(%{params: params} = state),
    do: params[:max_turn_rate] != nil and turn_rate(state) > params[:max_turn_rate]

  # the turn rate between the last two odometry readings, rad/s
  defp turn_rate(state) do
    case :queue.to_list(state.history) |> Enum.take(-2) do
      [{t0, {_, _, a0}}, {t1, {_, _, a1}}] when t1 > t0 ->
        abs(normalize_angle(a1 - a0)) / (t1 - t0)

      _ ->
        0.0
    end
  end

  @impl true
  def terminate(_reason, %{params: params} = state) do
    if params[:save], do: save(state, params[:save])
    :ok
  end

  ## loop closure

  # a pose the localizer estimated in an older frame of the map, carried
  # into the current one (nil: too old)
  defp in_frame(%{loops: nil}, pose, _frame), do: pose
  defp in_frame(%{loops: loops}, pose, frame), do: Loops.carry(loops, pose, frame)

  defp record(%{loops: nil} = state, _tag, _reading, _pose), do: {:none, state}

  defp record(state, tag, reading, pose) do
    case Map.fetch(state.lasers, tag) do
      {:ok, mount} ->
        odometry = odometry_at(state, Map.get(reading, :stamp))

        case Loops.record(state.loops, tag, mount, reading, pose, odometry) do
          {loops, :none} -> {:none, %{state | loops: loops}}
          {loops, {:closed, from, to}} -> {:closed, from, to, %{state | loops: loops}}
        end

      :error ->
        {:none, state}
    end
  end

  # a loop closed: the map drawn again from the kept scans at their
  # corrected poses, published at once with the move of its frame, so
  # that the localizer carries its particles along
  defp redraw(state, from, to) do
    grid = Loops.redraw(state.loops, blank_grid(state.params), state.lasers, state.footprint)

    estimate =
      with {pose, odom} <- state.estimate,
           do: {Loops.carry(state.loops, pose, Loops.frame(state.loops) - 1), odom}

    version = state.version + 1
    map = SensedGrid.occupancy(grid, version: version, stamp: state.stamp)
    frame = Loops.frame(state.loops)

    Logger.debug(
      "#{inspect(state.robot)}: loop closed (frame #{frame}): #{inspect(from)} is #{inspect(to)}"
    )

    correction = %{from: from, to: to, frame: frame, map: map, stamp: state.stamp}

    state = %{
      state
      | grid: grid,
        estimate: estimate,
        version: version,
        published: state.stamp,
        changed: false,
        last_map: map
    }

    {more, state} = publish_topology(state)
    {more2, state} = save_due(state)

    {[
       out: Tuples.keyed(Tuples.map(state.robot, map)),
       out: Tuples.keyed(Tuples.map_correction(state.robot, correction))
     ] ++ more ++ more2, state}
  end

  ## readings

  defp add(grid, %{type: :laser, pose: sensor}, scan, pose),
    do: SensedGrid.add_laser(grid, scan, EKF.motion(pose, sensor))

  defp add(grid, %{type: :sonar} = ring, reading, pose),
    do: SensedGrid.add_sonar(grid, reading, pose, ring)

  # the estimate moved on by the odometry from its stamp to `stamp`
  defp pose_at(%{estimate: nil}, _stamp), do: nil
  defp pose_at(%{estimate: {pose, nil}}, _stamp), do: pose

  defp pose_at(%{estimate: {pose, odom}} = state, stamp) do
    case odometry_at(state, stamp) do
      nil -> pose
      now -> EKF.motion(pose, EKF.relative(odom, now))
    end
  end

  # the odometry pose at a stamp: the latest reading not after it
  defp odometry_at(_state, nil), do: nil

  defp odometry_at(state, stamp) do
    state.history
    |> :queue.to_list()
    |> Enum.reduce(nil, fn {t, pose}, best -> if t <= stamp + 1.0e-9, do: pose, else: best end)
  end

  ## publishing

  defp due(state) do
    {actions, state} = publish_map(state)
    {more, state} = publish_topology(state)
    {more2, state} = save_due(state)
    {actions ++ more ++ more2, state}
  end

  defp publish_map(%{changed: false} = state), do: {[], state}

  defp publish_map(state) do
    if elapsed?(state.published, state.stamp, state.params[:publish_every]) do
      version = state.version + 1
      map = SensedGrid.occupancy(state.grid, version: version, stamp: state.stamp)
      tuple = Tuples.map(state.robot, map)

      {[out: Tuples.keyed(tuple)],
       %{state | version: version, published: state.stamp, changed: false, last_map: map}}
    else
      {[], state}
    end
  end

  defp publish_topology(%{last_map: nil} = state), do: {[], state}

  defp publish_topology(state) do
    if elapsed?(state.topology_at, state.stamp, state.params[:topology_every]) do
      opts = Keyword.take(state.params, [:door_width, :min_area])
      topology = state.last_map |> Rooms.from_occupancy(opts) |> Rooms.rename(state.topology)
      segments = Segments.from_occupancy(state.last_map)

      {[
         out: Tuples.keyed(Tuples.topology(state.robot, topology)),
         out:
           Tuples.keyed(Tuples.segments(state.robot, %{segments: segments, stamp: state.stamp}))
       ], %{state | topology: topology, topology_at: state.stamp}}
    else
      {[], state}
    end
  end

  defp save_due(%{params: params} = state) do
    if params[:save] && state.last_map &&
         elapsed?(state.saved_at, state.stamp, params[:save_every]) do
      {actions, state} = save(state, params[:save])
      {actions, %{state | saved_at: state.stamp}}
    else
      {[], state}
    end
  end

  defp save(state, path) do
    map =
      state.grid
      |> SensedGrid.occupancy(version: state.version, stamp: state.stamp)
      |> OccupancyGrid.crisp()

    _ = File.mkdir_p(Path.dirname(path))
    result = OccupancyGrid.save(map, path)

    case result do
      :ok -> Logger.info("#{inspect(state.robot)}: map saved to #{path}")
      {:error, reason} -> Logger.warning("#{inspect(state.robot)}: map not saved: #{reason}")
    end

    tuple = Tuples.map_saved(state.robot, %{path: path, result: result})
    {[out: Tuples.keyed(tuple)], state}
  end

  defp elapsed?(nil, _now, _period), do: true
  defp elapsed?(_last, nil, _period), do: true
  defp elapsed?(last, now, period), do: now - last >= period - 1.0e-9

  ## set-up

  defp new_grid(%WDF{} = wdf, params) do
    if WDF.empty?(wdf), do: {blank_grid(params), true}, else: {prior_grid(wdf, params), false}
  end

  defp new_grid(nil, params), do: {blank_grid(params), true}

  defp blank_grid(params) do
    {w, h} = params[:size]
    res = params[:resolution]
    {x, y} = point(params[:initial])
    {cols, rows} = {ceil(w / res), ceil(h / res)}
    origin = {x - cols * res / 2, y - rows * res / 2}
    SensedGrid.new(cols, rows, [resolution: res, origin: origin] ++ grid_opts(params))
  end

  defp prior_grid(wdf, params) do
    opts = if wdf.grid, do: [unknown: :free], else: [resolution: params[:resolution]]
    grid = Maps.grid_from_wdf(wdf, opts)
    SensedGrid.seeded(Maps.prior(wdf, grid), params[:prior], grid_opts(params))
  end

  # the grid's own defaults stand for the options not given
  defp grid_opts(params),
    do: params |> Keyword.take(@grid_opts) |> Enum.reject(fn {_key, v} -> v == nil end)

  # Beside a laser, a sonar only adds obstacles close by (what the laser
  # cannot see: behind the robot, glass, low things): its wide cone and
  # specular walls make its empty evidence wrong where the laser is right.
  defp sonar_degrees(sensors, params) do
    laser? = Enum.any?(sensors, fn {_, s} -> s.type == :laser end)
    base = if laser?, do: [k_empty: 0.0, k_occupied: 0.1, trust: 1.0], else: []
    Keyword.merge(base, Enum.to_list(params[:sonar] || []))
  end

  defp point({x, y}), do: {x * 1.0, y * 1.0}
  defp point({x, y, _}), do: {x * 1.0, y * 1.0}

  defp range_sensors(description) do
    for %{type: type} = s <- description.sensors, type in [:laser, :sonar], into: %{} do
      {s.name, Map.take(s, [:type, :pose, :ring_radius, :count, :range, :fov])}
    end
  end
end
