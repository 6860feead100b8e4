defmodule ThinkingCap.Planner.Monitor do
  @moduledoc """
  The Planner/Monitor as an ADF module (periodic): turns a task into
  plans and supervises their execution.

      planner: [module: ThinkingCap.Planner.Monitor, activity: :periodic, period: 0.5,
                params: [task: {:patrol, [:lab_bench, :desk_a, :dock]}]]

  Tasks (param `task:`, or later a `{:task, robot, %{task: task}}` tuple):
  `{:go_to, waypoint}`, `{:visit, [waypoint]}`, `{:patrol, [waypoint]}`
  (visits for ever), `:explore` and `:idle`. A waypoint is a point `{x, y}`, or a
  name: a waypoint of the WDF, a room or corridor of the WDF, or a place
  of the map the robot learned (`{:topology, robot, _}` from
  `ThinkingCap.Navigation.Mapper`: "go to `:room_3`"). A task that is
  not one of these, or a name nobody knows, is refused on the blackboard
  (state `:failed`, `reason` saying why); the module carries on.

  **Planning** is done on a map by `ThinkingCap.Navigation.PathPlanner`
  (obstacles grown by the robot's radius plus `margin`, unknown space
  free, D* Lite repairs): the map the robot builds, `{:map, robot, _}`
  from the map builder, as soon as one arrives; until then the WDF's
  (its walls, obstacles, closed doors and imported map; unknown cells of
  the imported map blocked). With a map builder, what the sensors see (a
  box, a person, a shut door) is in the map, and the path is repaired at
  the next cycle after a new map version (and every `replan_every`
  seconds while moving). Planning starts from the estimated pose
  (`{:pose, robot, _}`, from the localizer). A goal beyond the learned
  map (unexplored space, within `reach` metres of it) is planned to
  through unknown space.

  Where no path keeps the margin (a doorway drawn a little narrower than
  it is, a corner the robot drove into), on a sensed map, the path is
  planned again with the robot's own radius.

  **Exploring** (`:explore`, on the map the map builder builds; without
  one the task fails after `map_timeout` seconds, saying so): the robot
  visits frontiers between known free and unknown space
  (`ThinkingCap.Navigation.Frontiers`: the nearest and longest first,
  and with `area_gain` those opening onto the most unknown area; with
  `hysteresis`, on the way, every 5 s, a frontier cheaper by that many
  metres than the one aimed at is taken instead), a
  frontier seen from afar (no free cell near its point borders unknown
  space any more) is dropped for the next, one out of reach is
  given up (not chosen again in that round; see `explore_rounds`). A
  frontier is to be seen, not stood on: the path to it ends at a
  stand-in, within its last metre the first cell that sees the frontier
  with room round the robot (a frontier in a nook is looked into, not
  driven into); one its stand-in turns out not to see is left for the
  next round. When none is left the task is
  `:done` and, with `save_to: path`, the map builder is asked to save the
  map there (`{:save_map, robot, %{path: path}}`).

  **Docking.** A waypoint with a heading (`at: {x, y, theta}`) is a dock
  for a robot whose RDF has a `docking:` section: it is reached only
  within the RDF's `position_tolerance` and `heading_tolerance` (the
  control module, `ThinkingCap.Control.VehicleDrive` for a car-like robot,
  drives the final leg into it).

  **Monitoring**, every cycle: a waypoint within `tolerance` is reached
  and the next one taken; a robot that makes no progress for
  `stuck_after` seconds gets a new plan (on a sensed map, one wary of
  narrow gaps: see `wary_band`), and after `max_replans` the
  waypoint is given up (a task that gave up any of its waypoints ends
  `:failed`, not `:done`). On the WDF's map (no map builder), a door on
  the path seen shut in the LPS (`{:lps, robot, _}`: obstacle evidence,
  at least three points, across the middle of its opening while the
  robot is within 3 m) is marked closed and the path planned around it.
  A goal no path leads to (state `:unreachable`) or a route blocked
  (`:blocked`) is tried again after `retry_after` seconds, counted as a
  replan.

  **Published** as `{:plan, robot, %{task:, state:, waypoint:, goal:,
  heading:, docking:, path:, door:, closed_doors:, replans:, recoveries:,
  reached:, given_up:, reason:, source:, planning:, planned_at:}}` (latest
  value): `recoveries` counts the times the robot was found making no
  progress, over the whole run; each one asks the control module to back
  the robot off before it follows the new plan (`ThinkingCap.Control.Blender`:
  a robot pressed against a door jamb with no bumper to tell it stayed
  there until the task failed);
  `heading` is the waypoint's heading (or nil), `docking` the RDF's
  docking tolerances (or nil); `state` is `:waiting` (no pose or
  no map yet), `:moving`, `:blocked`, `:unreachable`, `:done` (every
  waypoint reached), `:failed` (the task ended with waypoints given up,
  or was refused) or `:idle`; `path` the rest of the metric path (world
  points); `door` the next door the path crosses (`%{name:, centre:,
  width:, heading:}`, heading across the opening in the direction of
  travel: the WDF's doors, and those of the learned topology; none while
  exploring on the sensed map, whose paths go through the openings as
  sensed); `reason`
  why the robot is not moving on (a sentence, or nil); `source` the map
  planned on (`:wdf`, `:sensed` or nil); `planning` what the last
  planning did (`ThinkingCap.Navigation.PathPlanner`'s `last`) and
  `planned_at` when (the cycle's time, s; `planning.us`, the search's
  duration, is the one output a replay cannot reproduce). Doors
  seen shut are also published as `{:door, name, %{open: false, stamp: t}}`.

  ## Parameters

  `task`, `tolerance` (0.35 m), `stuck_after` (12 s), `max_replans` (3),
  `retry_after` (10 s), `replan_every` (1 s), `margin` (0.08 m),
  `band` (m, default 0: none) and `band_cost` (200): a cost band beyond
  the margin (`ThinkingCap.Navigation.PathPlanner`: a plan keeps off
  gaps that leave the robot little room where the way round is not much
  longer). Off by default: on `mix tc.bench nav_unknown`, seeds 1 to 4,
  `band: 0.2` changed no run's outcome (30 of 32 before and after), bent
  path_ratio both ways (1.06 against 1.16 on seed 1, 1.33 against 1.05
  on seed 2: a warehouse run took the long way) and doubled D* Lite's
  repairs (each step of a walker changes its band too),
  `wary_band` (0.15 m: after no progress, the waypoint is planned with
  a cost band this wide beyond the margin at full cost, 255, so that
  the new plan keeps off gaps the behaviours refused; 0: replanned as
  before),
  `clearance` (m, default nil: off; the path is moved up to this far
  from the walls beyond the robot's radius where there is room,
  `ThinkingCap.Navigation.PathPlanner.keep_clear/2`. The explore example
  sets 0.35: it let an exploring robot drive faster. Off by default: on
  `mix tc.bench nav_unknown` it made one warehouse run stop 0.51 m from
  its goal, the estimate 0.25 m off),
  `radius` (default the RDF's footprint, else 0.2 m), `resolution` (the
  planning cell, default the map's, at least 0.05 m), `reach` (20 m),
  `compare` (time A* beside each plan, for benchmarks; default false),
  `map_timeout` (10 s), `save_to` (where an exploration's map is saved),
  `explore_rounds` (2: when no frontier is left but some were given up,
  they are tried again this many times in all, on the map as it is then),
  `frontier_gain` (1.0: m of way a metre of a frontier's length is
  worth, `ThinkingCap.Navigation.Frontiers.cost/3`'s `gain`),
  `area_gain` (m of way a square metre of unknown area within 3 m of a
  frontier is worth, counted up to 6 m²; default 0: the area does not
  count. At 2, on generated buildings 5 and 1 (seed 1) 8 and 10 points
  more coverage at 1,000 s, on building 21 17 points less: frontiers
  beyond the south wall, where a bent map drew free cells, open onto the
  unknown outside and looked rich; the office's second run 94.3 % against
  97.2) and `hysteresis` (m, default nil: the target is kept until seen
  or given up. At 2, without the area's gain, the same three buildings
  had 2 to 15 points less coverage at 600 s, the office and
  turtlebot3_world the same figures as without).
  """
  use ThinkingCap.Module
  require Logger

  alias ThinkingCap.Config.WDF
  alias ThinkingCap.Navigation.{Frontiers, Maps, OccupancyGrid, PathPlanner, Topology}
  alias ThinkingCap.Navigation.Core.{GridNif, ModuleContext}
  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples
  import ThinkingCap.Geometry, only: [angle_diff: 2, segment_distance: 3, to_frame: 2]

  @waypoint {:or, [:place, :point]}
  @task {:or,
         [
           {:one_of, [:idle, :explore]},
           {:tuple, [{:one_of, [:go_to]}, @waypoint]},
           {:tuple, [{:one_of, [:visit, :patrol]}, {:list, @waypoint}]}
         ]}
  @params [
    task:
      {@task,
       default: :idle,
       read_only: true,
       doc: "the first task (later ones: a {:task, robot, %{task: t}} tuple)"},
    tolerance: {:pos_number, default: 0.35, doc: "m from a waypoint that reaches it"},
    stuck_after: {:pos_number, default: 12.0, doc: "s without progress before a new plan"},
    max_replans: {:non_neg_integer, default: 3, doc: "new plans before a waypoint is given up"},
    retry_after:
      {:non_neg_number, default: 10.0, doc: "s before an unreachable goal is tried again"},
    replan_every: {:pos_number, default: 1.0, doc: "s between plans while moving"},
    resolution:
      {:pos_number,
       default: nil, read_only: true, doc: "planning cell, m (the map's; at least 0.05)"},
    margin:
      {:non_neg_number, default: 0.08, read_only: true, doc: "m kept beyond the robot's radius"},
    band:
      {:non_neg_number,
       default: 0.0, read_only: true, doc: "m beyond the margin where cells cost more (0: none)"},
    wary_band:
      {:non_neg_number,
       default: 0.15, doc: "m of cost band beyond the margin after no progress (0: none)"},
    band_cost:
      {{:int_range, 2, 255},
       default: 200, read_only: true, doc: "a cell's cost at the margin, falling across the band"},
    clearance:
      {:non_neg_number,
       default: nil, read_only: true, doc: "m from the walls the path moves up to (nil: off)"},
    radius: {:pos_number, default: nil, read_only: true, doc: "robot radius, m (the RDF's)"},
    reach: {:non_neg_number, default: 20.0, doc: "m into unknown space a goal is planned to"},
    compare: {:boolean, default: false, read_only: true, doc: "time A* beside each plan"},
    map_timeout: {:pos_number, default: 10.0, doc: "s an exploration waits for a map"},
    save_to: {:string, default: nil, doc: "where an exploration's map is saved"},
    explore_rounds: {:pos_integer, default: 2, doc: "rounds over the frontiers given up"},
    frontier_gain:
      {:non_neg_number, default: 1.0, doc: "m of way a metre of a frontier's length is worth"},
    area_gain:
      {:non_neg_number,
       default: 0.0, doc: "m of way a m² of unknown area a frontier opens onto is worth"},
    hysteresis:
      {:non_neg_number,
       default: nil,
       doc: "m by which another frontier must be cheaper to be taken on the way (nil: never)"}
  ]
  @defaults ThinkingCap.Config.Schema.defaults(@params)

  @doc "The params this module takes (`c:ThinkingCap.Module.params/0`)."
  @impl true
  @spec params() :: keyword()
  def params, do: @params

  @doc """
  A live change of a param read as the task runs (`tolerance`,
  `stuck_after`, `max_replans`, `retry_after`, `replan_every`, `reach`,
  `map_timeout`, `save_to`, `explore_rounds`, `wary_band`, `area_gain`,
  `hysteresis`): the next
  cycle uses it.
  Those that made the planner (`margin`, `band`, `band_cost`, `clearance`, `radius`,
  `resolution`, `compare`) and the first `task` are read-only.
  """
  @impl true
  def handle_param(key, value, state),
    do: {[], %{state | params: Keyword.put(state.params, key, value)}}

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, if(is_map(params), do: Map.to_list(params), else: params))
    wdf = ModuleContext.read_wdf(context)
    radius = robot_radius(context, params)
    planner = new_planner(params, radius, params[:band], params[:band_cost])

    state = %{
      robot: context.robot,
      params: params,
      wdf: wdf,
      places: if(wdf, do: Topology.from_wdf(wdf).places, else: %{}),
      learned: nil,
      closed: initially_closed(wdf),
      planner: planner,
      source: nil,
      incoming: nil,
      map: nil,
      pose: nil,
      lps: nil,
      time: 0.0,
      task: :idle,
      queue: [],
      target: nil,
      stand_in: nil,
      wary: nil,
      looking: nil,
      faced: nil,
      chosen_at: nil,
      frontier: nil,
      map_at: nil,
      plan: nil,
      status: :idle,
      reason: nil,
      reached: [],
      given_up: [],
      rounds: 1,
      replans: 0,
      recoveries: 0,
      progress: nil,
      blocked_at: nil,
      planned_at: nil,
      waiting_since: nil,
      docking: robot_docking(context)
    }

    state =
      state
      |> wdf_map()
      |> set_task(Keyword.get(params, :task, :idle))
      |> resume(Map.get(context, :handoff))

    {[
       subscribe: Tuples.pose(context.robot),
       subscribe: Tuples.lps(context.robot),
       subscribe: Tuples.task(context.robot),
       subscribe: Tuples.map(context.robot),
       subscribe: Tuples.topology(context.robot)
     ], state}
  end

  @doc """
  What a replay cannot reproduce (`c:ThinkingCap.Module.replay/0`): the
  planning's duration, measured on the machine it ran on, on the wall
  clock and in CPU time (`planning.us` and `planning.cpu_us`, and
  `planning.astar_us` and `planning.astar_cpu_us` with `compare: true`).
  """
  @impl true
  @spec replay() :: keyword()
  def replay,
    do: [
      measurements:
        for(key <- [:us, :cpu_us, :astar_us, :astar_cpu_us], do: {:plan, [:planning, key]})
    ]

  @doc """
  What a standby needs to carry on (`c:ThinkingCap.Module.handoff/1`): the
  task, where it stands in it (the waypoint it is heading for and those
  left) and what it reached and gave up. The plan itself is made afresh.
  """
  @impl true
  @spec handoff(map()) :: map()
  def handoff(state),
    do: Map.take(state, [:task, :queue, :target, :reached, :given_up, :closed])

  # after a failover: on with the task where it stood
  defp resume(state, %{task: _, queue: _, target: _, reached: _, given_up: _} = handoff) do
    status = if handoff.target == nil and handoff.queue == [], do: state.status, else: :waiting
    state |> Map.merge(Map.put(handoff, :status, status)) |> wdf_map()
  end

  defp resume(state, _handoff), do: state

  @impl true
  def handle_tuple(Tuples.pose(robot, %{pose: {x, y, th} = pose}), %{robot: robot} = state)
      when is_number(x) and is_number(y) and is_number(th),
      do: {[], %{state | pose: pose}}

  def handle_tuple(Tuples.lps(robot, %LPS{} = lps), %{robot: robot} = state),
    do: {[], %{state | lps: lps}}

  def handle_tuple(Tuples.task(robot, %{task: task}), %{robot: robot} = state),
    do: {[], set_task(state, task)}

  def handle_tuple(Tuples.map(robot, %OccupancyGrid{} = map), %{robot: robot} = state),
    do: {[], %{state | incoming: map}}

  def handle_tuple(Tuples.topology(robot, %Topology{} = topology), %{robot: robot} = state),
    do: {[], %{state | learned: topology}}

  def handle_tuple(_tuple, state), do: {[], state}

  @impl true
  def handle_cycle(release, state) do
    state = %{state | time: release.scheduled_ns / 1.0e9} |> take_map()
    before = state.status
    {actions, state} = step(state)
    {actions ++ explored(before, state) ++ [publish(state)], state}
  end

  ## Maps

  # the sensed map, once one came: it replaces the WDF's for good
  defp take_map(%{incoming: nil} = state), do: state

  defp take_map(%{incoming: map} = state) do
    map = keep_frame(map, state.map)
    planner = PathPlanner.set_map(state.planner, map)
    %{state | map: map, source: :sensed, incoming: nil, planner: planner, map_at: state.time}
  end

  # a map that fits in the frame planned on (widened towards a goal in
  # unexplored space) is padded out to it: the same frame, so the plan is
  # repaired rather than searched again
  defp keep_frame(map, %OccupancyGrid{resolution: res} = frame) when res == map.resolution do
    {{fx, fy}, {mx, my}} = {frame.origin, map.origin}
    {left, bottom} = {round((mx - fx) / res), round((my - fy) / res)}
    right = frame.width - map.width - left
    top = frame.height - map.height - bottom
    aligned = abs(fx + left * res - mx) < res / 100 and abs(fy + bottom * res - my) < res / 100

    if aligned and left >= 0 and bottom >= 0 and right >= 0 and top >= 0 and
         {left, bottom, right, top} != {0, 0, 0, 0},
       do: OccupancyGrid.pad(map, left, bottom, right, top),
       else: map
  end

  defp keep_frame(map, _frame), do: map

  # the WDF's map (with the doors known to be closed), while nothing is sensed
  defp wdf_map(%{source: :sensed} = state), do: state
  defp wdf_map(%{wdf: nil} = state), do: state

  defp wdf_map(%{wdf: wdf} = state) do
    if WDF.empty?(wdf) do
      state
    else
      opts = [closed: MapSet.to_list(state.closed)]
      opts = if wdf.grid, do: opts, else: [{:resolution, 0.05} | opts]
      grid = Maps.grid_from_wdf(wdf, opts)
      # blocked cells occupied (100), the rest free: in C (a warehouse
      # map has 1.7 million cells)
      data = GridNif.overlay(:binary.copy(<<0>>, byte_size(grid.cells)), grid.cells, 100)

      map = %OccupancyGrid{
        width: grid.width,
        height: grid.height,
        data: data,
        resolution: grid.resolution,
        origin: grid.origin,
        version: {:wdf, Enum.sort(state.closed)}
      }

      %{state | map: map, source: :wdf, planner: PathPlanner.set_map(state.planner, map)}
    end
  end

  ## Tasks

  defp set_task(state, task) do
    case queue(task) do
      {:ok, queue} ->
        %{
          state
          | task: task,
            queue: queue,
            target: nil,
            plan: nil,
            reached: [],
            given_up: [],
            rounds: 1,
            replans: 0,
            reason: nil
        }
        |> Map.put(:status, if(queue == [] and task != :explore, do: :idle, else: :waiting))

      {:error, reason} ->
        Logger.warning("#{inspect(state.robot)}: task refused: #{reason}")

        %{state | task: :idle, queue: [], target: nil, plan: nil}
        |> Map.merge(%{status: :failed, reason: reason})
    end
  end

  defp queue(task) do
    waypoints =
      case task do
        {:go_to, wp} -> {:ok, [wp]}
        {:visit, wps} when is_list(wps) -> {:ok, wps}
        {:patrol, [_ | _] = wps} -> {:ok, wps}
        :idle -> {:ok, []}
        :explore -> {:ok, []}
        other -> {:error, "unknown task #{inspect(other, limit: 5, printable_limit: 40)}"}
      end

    with {:ok, wps} <- waypoints do
      case Enum.reject(wps, &waypoint?/1) do
        [] -> {:ok, wps}
        [bad | _] -> {:error, "#{inspect(bad, limit: 5, printable_limit: 40)} is not a waypoint"}
      end
    end
  end

  defp waypoint?(name) when is_atom(name), do: true

  defp waypoint?({x, y}) when is_number(x) and is_number(y),
    do: abs(x) < 1.0e6 and abs(y) < 1.0e6

  defp waypoint?(_), do: false

  ## Monitoring

  defp step(%{pose: nil} = state), do: {[], state}

  defp step(%{status: status} = state) when status in [:idle, :done, :failed],
    do: {[], state}

  defp step(%{task: :explore, source: source} = state) when source != :sensed do
    waited = state.time - (state.waiting_since || state.time)

    if waited >= state.params[:map_timeout] do
      reason =
        "exploring needs a map builder (ThinkingCap.Navigation.Mapper) in the ADF: " <>
          "no map came in #{round(waited)} s"

      Logger.warning("#{inspect(state.robot)}: #{reason}")
      {[], %{state | status: :failed, reason: reason, task: :idle}}
    else
      {[],
       %{
         state
         | status: :waiting,
           reason: "waiting for the map builder's first map",
           waiting_since: state.waiting_since || state.time
       }}
    end
  end

  defp step(%{map: nil} = state),
    do: {[], %{state | status: :waiting, reason: "no map yet: no WDF and no map builder"}}

  # resumed from a handoff with a waypoint under way: plan to it from here
  defp step(%{status: :waiting, target: target, plan: nil} = state) when target != nil,
    do: {[], plan(state)}

  defp step(%{task: :explore, target: nil} = state) do
    {x, y, _} = state.pose
    frontiers = Frontiers.find(state.map, frontier_opts(state))

    # the robot's own cell free, and more than its footprint seen free:
    # the first maps may hold only the ground under the robot and a few
    # sonar echoes
    seen_around? = fn ->
      OccupancyGrid.value(state.map, OccupancyGrid.cell_of(state.map, {x, y})) in 0..49 and
        free_area(state.map) >= 4.0
    end

    {distances, state} = frontier_distances(frontiers, state)

    choice =
      Frontiers.choose(
        frontiers,
        {x, y},
        [blacklist: state.given_up, distances: distances] ++ frontier_opts(state)
      )

    again? = state.given_up != [] and state.rounds < state.params[:explore_rounds]

    case if(choice == nil and not seen_around?.(), do: :unseen, else: choice) do
      # the first maps may hold nothing but a few echoes
      :unseen ->
        {[], %{state | status: :waiting, reason: "waiting for the map around the robot"}}

      # frontiers given up on a map since drawn again (a loop closed, a
      # door seen open) may be reachable now: another round tries them
      nil when again? ->
        Logger.info(
          "#{inspect(state.robot)}: trying again #{length(state.given_up)} frontiers given up"
        )

        step(%{state | given_up: [], rounds: state.rounds + 1})

      nil ->
        {[], %{state | status: :done, reason: "explored: no frontier left"}}

      %{point: point} = f ->
        Logger.debug(
          "#{inspect(state.robot)}: frontier #{inspect(point)} of #{length(frontiers)}: " <>
            "#{fmt(distances && distances[point])} m away, #{fmt(f.area)} m² unknown"
        )

        {[],
         plan(%{
           state
           | target: point,
             replans: 0,
             looking: nil,
             faced: nil,
             chosen_at: state.time,
             frontier: f
         })}
    end
  end

  defp step(%{target: nil, queue: [], given_up: []} = state), do: {[], %{state | status: :done}}
  defp step(%{target: nil, queue: []} = state), do: {[], %{state | status: :failed}}

  defp step(%{target: nil} = state) do
    [next | rest] = state.queue
    queue = if match?({:patrol, _}, state.task), do: rest ++ [next], else: rest
    state = %{state | target: next, queue: queue, replans: 0}
    {[], plan(state)}
  end

  defp step(%{status: status} = state) when status in [:blocked, :unreachable] do
    if state.time - state.blocked_at >= state.params[:retry_after] do
      # doors open again: forget what was seen shut, try again
      state = %{state | closed: initially_closed(state.wdf)} |> wdf_map()
      retry(state)
    else
      {[], state}
    end
  end

  defp step(state) do
    {x, y, _} = state.pose

    case aim(state) do
      {:ok, {tx, ty}} ->
        distance = :math.sqrt((tx - x) ** 2 + (ty - y) ** 2)
        {to_go, state} = to_go(state, distance)
        monitor(state, distance, to_go)

      {:error, reason} ->
        give_up(state, reason)
    end
  end

  defp monitor(state, distance, to_go) do
    case better_frontier(state, distance) do
      {:switch, state} -> {[], state}
      {:keep, state} -> keep_on(state, distance, to_go)
    end
  end

  defp keep_on(state, distance, to_go) do
    cond do
      # within reach of a frontier not yet seen, not facing it (one just
      # beside or behind the robot, where the laser does not look): the
      # robot turns to it, driving to the frontier itself, for at most
      # @look_for seconds, before it counts as unseen. Judged at once,
      # the office's first frontier, 0.26 m from where the robot
      # started, was given up, and the exploration ended there after 10 s.
      reached?(state, distance) and state.task == :explore and not explored?(state) and
        not facing?(state) and still_looking?(state) ->
        if state.looking,
          do: {[], state},
          else: {[], plan(%{state | looking: state.time})}

      # facing it now: judged on a map made after the robot turned to it,
      # not on the one it had (the mapper publishes once a second). On
      # the map of before the turn, the office's first frontier was given
      # up half a second into an exploration, and the exploration ended.
      reached?(state, distance) and state.task == :explore and not explored?(state) and
        facing?(state) and not seen_since_facing?(state) and not faced_long?(state) ->
        {[], %{state | faced: state.faced || state.time}}

      reached?(state, distance) ->
        # a frontier its stand-in does not see (round a corner) is left
        # for the next round, not chosen again at once
        state =
          if state.task == :explore and not explored?(state),
            do: %{state | given_up: [state.target | state.given_up]},
            else: state

        state = %{state | reached: [state.target | state.reached], target: nil, plan: nil}
        step(state)

      explored?(state) ->
        # the frontier was seen from afar: on to the next
        step(%{state | target: nil, plan: nil})

      door = shut_door(state) ->
        Logger.info("#{inspect(state.robot)}: door #{door.name} is shut; replanning")
        state = %{state | closed: MapSet.put(state.closed, door.name)} |> wdf_map()
        seen = Tuples.keyed(Tuples.door(door.name, %{open: false, stamp: state.time}))
        {[out: seen], plan(state)}

      stuck?(state, to_go) ->
        # the control module backs the robot off (recoveries below)
        retry(%{state | recoveries: state.recoveries + 1})

      replan_due?(state) ->
        {[], plan(state, keep_progress: true)}

      true ->
        {[], %{state | progress: progress(state.progress, to_go, state.time)}}
    end
  end

  # Exploring, on the way to a frontier: every @rechoose_every seconds
  # the frontiers are weighed again from where the robot is, and one
  # cheaper than the target by more than `hysteresis` metres is taken
  # instead (a room passed on the way, a frontier the new map shows
  # nearer). The target's cost is that of the frontier now found within
  # a metre of its point (a frontier's point moves as it is seen), else
  # that of the frontier as chosen. Not while looking at a frontier.
  @rechoose_every 5.0

  defp better_frontier(%{task: :explore, looking: nil, faced: nil} = state, distance) do
    if state.params[:hysteresis] == nil or reached?(state, distance) or
         state.time - (state.chosen_at || state.time) < @rechoose_every do
      {:keep, state}
    else
      switch_frontier(%{state | chosen_at: state.time})
    end
  end

  defp better_frontier(state, _distance), do: {:keep, state}

  defp switch_frontier(%{pose: {x, y, _}, target: target} = state) do
    opts = frontier_opts(state)
    frontiers = Frontiers.find(state.map, opts)
    {distances, state} = frontier_distances(frontiers, state, [target])
    {near, others} = Enum.split_with(frontiers, &(dist(&1.point, target) < 1.0))

    best =
      Frontiers.choose(
        others,
        {x, y},
        [blacklist: state.given_up, distances: distances] ++ opts
      )

    with %{point: point} = f <- best,
         here when here != nil <- distances && distances[target],
         current = Enum.min_by(near, &dist(&1.point, target), fn -> state.frontier end),
         now = if(current, do: Frontiers.cost(current, here, opts), else: here),
         better = Frontiers.cost(f, distances[point], opts),
         true <- better < now - state.params[:hysteresis] do
      Logger.debug(
        "#{inspect(state.robot)}: frontier #{inspect(point)} instead of #{inspect(target)}: " <>
          "cost #{fmt(better)} against #{fmt(now)}"
      )

      {:switch, plan(%{state | target: point, frontier: f, replans: 0, looking: nil, faced: nil})}
    else
      _ -> {:keep, state}
    end
  end

  # the frontiers' unknown areas are counted only when they weigh
  defp frontier_opts(state) do
    gain = state.params[:area_gain]
    [gain: state.params[:frontier_gain], area_gain: gain, area: is_number(gain) and gain > 0]
  end

  defp fmt(nil), do: "?"
  defp fmt(v), do: :erlang.float_to_binary(v * 1.0, decimals: 2)

  # the length of the way to each frontier on the map as planned on: one
  # search from the robot (nil when the robot's cell is blocked: then the
  # straight line)
  defp frontier_distances(frontiers, %{pose: {x, y, _}} = state, extra \\ []) do
    planner = PathPlanner.set_map(state.planner, state.map)
    points = Enum.map(frontiers, & &1.point) ++ extra
    lengths = PathPlanner.distances(planner, {x, y}, points)
    state = %{state | planner: planner}

    if frontiers != [] and Enum.all?(lengths, &is_nil/1),
      do: {nil, state},
      else: {Map.new(Enum.zip(points, lengths)), state}
  end

  # square metres of the map seen free
  defp free_area(%OccupancyGrid{data: data, resolution: res}) do
    free = for <<v::signed-8 <- data>>, v in 0..49, reduce: 0, do: (n -> n + 1)
    free * res * res
  end

  # The frontier is gone once no free cell near its point borders unknown
  # space. Unknown space alone near it did not do: beside a wall, the
  # unknown cells behind the wall kept the frontier, and the robot drove to
  # its stand-in and gave it up (generated building 21: 25 frontiers given
  # up in 1,600 s, 670 s spent on them; judged so, 4 in 1,000 s).
  defp explored?(%{task: :explore, target: target, map: map}),
    do: not Frontiers.remains?(map, target, state_radius())

  defp explored?(_state), do: false

  # how near a frontier's point unknown space must stay for it to be one
  defp state_radius, do: 0.5

  # an exploration just done: the map saved where asked
  defp explored(before, %{task: :explore, status: :done} = state) when before != :done do
    Logger.info("#{inspect(state.robot)}: explored: no frontier left")

    case state.params[:save_to] do
      nil -> []
      path -> [out: Tuples.save_map(state.robot, %{path: Path.expand(path)})]
    end
  end

  defp explored(_before, _state), do: []

  # another plan, or the waypoint given up after max_replans
  defp retry(state) do
    if state.replans >= state.params[:max_replans] do
      give_up(state, state.reason || "no progress")
    else
      {[], state |> wary() |> Map.update!(:replans, &(&1 + 1)) |> plan()}
    end
  end

  # No progress: the way planned may lead through a gap the planner fits
  # by a few centimetres and the behaviours refuse (the obstacle
  # avoidance turns back at `stop` of clearance ahead). Until the
  # waypoint is reached or given up, it is planned with a cost band of
  # `wary_band` beyond the margin at full cost: such gaps are then taken
  # only when the way round is much longer (a step by an obstacle at the
  # margin costs about 30 times its length), and none is closed.
  defp wary(%{wary: nil, source: :sensed} = state) do
    band = state.params[:wary_band]

    if band > 0,
      do: %{replanner(state, band, 255) | wary: state.target},
      else: state
  end

  defp wary(state), do: state

  # the planner of the params again, for a new waypoint
  defp unwary(%{wary: nil} = state), do: state
  defp unwary(%{wary: target, target: target} = state), do: state

  defp unwary(state),
    do: %{replanner(state, state.params[:band], state.params[:band_cost]) | wary: nil}

  # the state with a planner of this cost band on the map planned on
  defp replanner(state, band, band_cost) do
    radius = state.planner.radius - state.params[:margin]
    planner = new_planner(state.params, radius, band, band_cost)
    %{state | planner: if(state.map, do: PathPlanner.set_map(planner, state.map), else: planner)}
  end

  defp new_planner(params, radius, band, band_cost) do
    PathPlanner.new(
      radius: radius + params[:margin],
      band: band,
      band_cost: band_cost,
      resolution: max(params[:resolution] || 0.05, 0.05),
      compare: params[:compare],
      clearance: if(params[:clearance], do: radius + params[:clearance])
    )
  end

  defp give_up(state, reason) do
    Logger.info("#{inspect(state.robot)}: giving up #{inspect(state.target)}: #{reason}")
    state = %{state | given_up: [state.target | state.given_up], target: nil, plan: nil}
    {actions, state} = step(state)
    {actions, %{state | reason: reason}}
  end

  # on a sensed map, the path is repaired when the map changed, and now
  # and then anyway (the robot strays from it)
  defp replan_due?(%{source: :sensed} = state) do
    state.planned_at == nil or
      state.time - state.planned_at >= state.params[:replan_every] or
      state.planner.version != state.map.version
  end

  defp replan_due?(_state), do: false

  # Progress is measured along the plan, not as the straight distance to
  # the target: a route that first leads away from the target (round the
  # end of a rack) is progress too. The robot's place on its path is its
  # projection, searched from the last one and at most @lookahead metres
  # on, so that a path passing near again later is not taken for progress.
  @lookahead 3.0

  defp to_go(%{plan: %{path: [_, _ | _] = path, s: s0} = plan, pose: {x, y, _}} = state, _d) do
    {s, off} = project(path, {x, y}, s0, s0 + @lookahead)
    {plan.length - s + off, %{state | plan: %{plan | s: s}}}
  end

  defp to_go(state, distance), do: {distance, state}

  # {arc length of the projection of point on path within [lo, hi], distance to it}
  defp project(path, point, lo, hi) do
    path
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.reduce({0.0, {lo, :infinity}}, fn [a, b], {start, best} ->
      len = dist(a, b)

      best =
        if start <= hi and start + len >= lo do
          t =
            if len > 0,
              do: clamp(dot(sub(point, a), sub(b, a)) / (len * len), 0.0, 1.0),
              else: 0.0

          s = max(start + t * len, lo)
          off = dist(point, lerp(a, b, (s - start) / max(len, 1.0e-9)))
          if off < elem(best, 1), do: {s, off}, else: best
        else
          best
        end

      {start + len, best}
    end)
    |> elem(1)
  end

  defp path_length(path),
    do:
      path
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.reduce(0.0, fn [a, b], l -> l + dist(a, b) end)

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
  defp sub({ax, ay}, {bx, by}), do: {ax - bx, ay - by}
  defp dot({ax, ay}, {bx, by}), do: ax * bx + ay * by
  defp clamp(v, lo, hi), do: v |> max(lo) |> min(hi)
  defp lerp({x1, y1}, {x2, y2}, t), do: {x1 + t * (x2 - x1), y1 + t * (y2 - y1)}

  # the best distance to the target so far, and when it was reached
  defp progress({best, _since}, distance, time) when distance < best - 0.2, do: {distance, time}
  defp progress(nil, distance, time), do: {distance, time}
  defp progress(p, _distance, _time), do: p

  defp stuck?(%{progress: nil}, _distance), do: false

  defp stuck?(%{progress: {best, since}} = state, distance),
    do: distance >= best - 0.2 and state.time - since > state.params[:stuck_after]

  ## Planning

  defp plan(state, opts \\ []) do
    state = unwary(state)
    {x, y, _} = state.pose

    with {:ok, goal} <- goal(state, state.target),
         {:ok, cells, planner, state} <- path_to(state, {x, y}, goal) do
      {cells, goal} = stand_in(state, goal, cells, planner)
      path = PathPlanner.keep_clear(planner, Enum.dedup(simplify(cells) ++ [goal]))
      length = path_length(path)
      progress = if opts[:keep_progress], do: state.progress, else: {length, state.time}

      %{
        state
        | planner: planner,
          stand_in: if(state.task == :explore, do: goal),
          plan: %{path: path, length: length, s: 0.0},
          status: :moving,
          reason: nil,
          progress: progress,
          planned_at: state.time
      }
    else
      {:error, reason, planner} -> not_planned(%{state | planner: planner}, reason)
      {:error, reason} -> elem(give_up(state, reason), 1)
    end
  end

  # Exploring, a frontier is to be seen, not stood on: its point may lie
  # where the robot does not fit, or only just (by a wall, in a nook),
  # and driving there would push the robot against the walls until it
  # gave up. The path then ends at a stand-in: going back from its end
  # over at most a metre, among the cells that see the frontier's point,
  # the first with room round the robot (0.1 m more than the planner's
  # radius), else the one with the most. The frontier stays the target
  # (planned to, seen or given up). A robot looking at a frontier
  # (`looking`, below) drives to the frontier itself.
  defp stand_in(%{task: :explore, looking: nil}, goal, [_ | _] = cells, planner) do
    last = List.last(cells)
    room = planner.radius + 0.1

    {_, _, {best, _}} =
      cells
      |> Enum.reverse()
      |> Enum.reduce_while({last, 0.0, {last, -1.0}}, fn cell, {prev, walked, best} ->
        walked = walked + dist(prev, cell)
        clear = PathPlanner.clearance(planner, cell)

        cond do
          walked > 1.0 -> {:halt, {prev, walked, best}}
          not PathPlanner.in_sight?(planner, cell, goal) -> {:cont, {cell, walked, best}}
          clear >= room -> {:halt, {cell, walked, {cell, clear}}}
          clear > elem(best, 1) -> {:cont, {cell, walked, {cell, clear}}}
          true -> {:cont, {cell, walked, best}}
        end
      end)

    kept = Enum.take_while(cells, &(&1 != best))
    {kept, best}
  end

  defp stand_in(_state, goal, cells, _planner), do: {cells, goal}

  # the point the robot drives to: the target, or its stand-in
  defp aim(%{stand_in: {_, _} = point, plan: %{}}), do: {:ok, point}
  defp aim(state), do: goal(state, state.target)

  defp path_to(state, from, goal) do
    case PathPlanner.plan(state.planner, from, goal) do
      {:ok, cells, planner} ->
        {:ok, cells, planner, state}

      {:error, :goal_outside_map, planner} when state.source == :sensed ->
        # beyond what was sensed: through unknown space, if near enough
        with {:ok, map} <- widen(state.map, goal, state.params[:reach]),
             planner = PathPlanner.set_map(planner, map),
             {:ok, cells, planner} <- PathPlanner.plan(planner, from, goal) do
          {:ok, cells, planner, %{state | map: map}}
        else
          :error -> {:error, :goal_outside_map, planner}
          error -> error
        end

      {:error, reason, planner}
      when reason in [:no_path, :start_blocked] and state.source == :sensed ->
        squeeze(state, planner, from, goal, reason)

      error ->
        error
    end
  end

  # No way with the margin: a doorway drawn narrower than it is (a wall
  # seen a little off), or the robot in a corner it drove into. Planned
  # again with the robot's own radius, the path keeps to free space the
  # robot fits in; the behaviours steer it clear of the walls.
  defp squeeze(state, planner, from, goal, reason) do
    tight =
      PathPlanner.new(
        radius: planner.radius - state.params[:margin] + 0.02,
        band: planner.band,
        band_cost: planner.band_cost,
        resolution: planner.resolution
      )
      |> PathPlanner.set_map(state.map)

    case PathPlanner.plan(tight, from, goal) do
      {:ok, cells, _tight} -> {:ok, cells, planner, state}
      {:error, _, _} -> {:error, reason, planner}
    end
  end

  # the map grown (unknown) to hold the goal with a margin, if the goal is
  # within `reach` of it
  defp widen(%OccupancyGrid{} = map, {gx, gy}, reach) do
    {ox, oy} = map.origin
    res = map.resolution
    {x1, y1} = {ox + map.width * res, oy + map.height * res}

    if gx > ox - reach and gx < x1 + reach and gy > oy - reach and gy < y1 + reach do
      pad = 40
      left = max(0, ceil((ox - gx) / res) + pad)
      bottom = max(0, ceil((oy - gy) / res) + pad)
      right = max(0, ceil((gx - x1) / res) + pad)
      top = max(0, ceil((gy - y1) / res) + pad)
      padded = OccupancyGrid.pad(map, left, bottom, right, top)
      {:ok, %{padded | version: {:widened, map.version, left, bottom, right, top}}}
    else
      :error
    end
  end

  defp not_planned(state, reason) do
    {status, sentence} =
      case reason do
        :no_map -> {:waiting, "no map yet"}
        :no_path -> {:unreachable, "no path to #{inspect(state.target)} on the map as known"}
        :goal_blocked -> {:blocked, "#{inspect(state.target)} lies in an obstacle"}
        :start_blocked -> {:blocked, "the robot is inside an obstacle as mapped"}
        :start_outside_map -> {:blocked, "the robot is off the map"}
        :goal_outside_map -> {:gone, "#{inspect(state.target)} is outside the map"}
      end

    Logger.info("#{inspect(state.robot)}: no plan to #{inspect(state.target)}: #{sentence}")

    case status do
      # a frontier out of reach is left for the next
      _ when state.task == :explore -> elem(give_up(state, sentence), 1)
      :gone -> elem(give_up(state, sentence), 1)
      _ -> %{state | plan: nil, status: status, reason: sentence, blocked_at: state.time}
    end
  end

  # every 8th point, and the ends
  defp simplify(path) when length(path) <= 2, do: path

  defp simplify(path) do
    path
    |> Enum.with_index()
    |> Enum.filter(fn {_p, i} -> rem(i, 8) == 0 end)
    |> Enum.map(&elem(&1, 0))
  end

  defp initially_closed(nil), do: MapSet.new()
  defp initially_closed(wdf), do: wdf.doors |> Enum.reject(& &1.open) |> MapSet.new(& &1.name)

  ## Docking

  # at a waypoint with a heading, a robot whose RDF has docking: must stop
  # within its docking tolerances
  # whether the robot faces the target (within 0.5 rad): the laser sees
  # ahead, and what lies close beside the robot only when it faces it. A
  # target under the robot (within 0.15 m) has no direction to face.
  defp facing?(%{pose: {x, y, th}, target: {tx, ty}}) do
    (tx - x) ** 2 + (ty - y) ** 2 < 0.15 ** 2 or
      abs(angle_diff(:math.atan2(ty - y, tx - x), th)) < 0.5
  end

  defp facing?(_state), do: true

  # a look at a frontier lasts at most @look_for seconds (time to turn
  # round and close in)
  @look_for 8.0
  # a map came after the robot first faced the frontier it stands at
  defp seen_since_facing?(%{faced: nil}), do: false
  defp seen_since_facing?(%{faced: faced, map_at: at}), do: at != nil and at > faced

  # ... or none for @look_for seconds (the map builder gone quiet)
  defp faced_long?(%{faced: nil}), do: false
  defp faced_long?(%{faced: faced, time: now}), do: now - faced >= @look_for

  defp still_looking?(%{looking: nil}), do: true
  defp still_looking?(%{looking: since, time: now}), do: now - since < @look_for

  defp reached?(state, distance) do
    case {state.docking, target_heading(state, state.target)} do
      {%{position_tolerance: p, heading_tolerance: h}, heading} when is_number(heading) ->
        {_, _, th} = state.pose
        distance <= p and abs(angle_diff(th, heading)) <= h

      _ ->
        distance <= state.params[:tolerance]
    end
  end

  defp target_heading(%{wdf: %WDF{} = wdf}, name) when is_atom(name) do
    case Enum.find(wdf.waypoints, &(&1.name == name)) do
      %{at: {_, _, th}} -> th * 1.0
      _ -> nil
    end
  end

  defp target_heading(_state, _target), do: nil

  defp robot_docking(%{rdf: rdf}) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, %{docking: %{} = docking}} ->
        Map.take(docking, [:position_tolerance, :heading_tolerance])

      _ ->
        nil
    end
  end

  defp robot_docking(_context), do: nil

  ## Goals

  defp goal(_state, {x, y}) when is_number(x) and is_number(y), do: {:ok, {x * 1.0, y * 1.0}}

  defp goal(state, name) when is_atom(name) do
    waypoints = if state.wdf, do: state.wdf.waypoints, else: []
    learned = if state.learned, do: state.learned.places, else: %{}

    case Enum.find(waypoints, &(&1.name == name)) do
      %{at: at} ->
        {:ok, {elem(at, 0) * 1.0, elem(at, 1) * 1.0}}

      nil ->
        case Map.get(learned, name) || Map.get(state.places, name) do
          %{centroid: centre} -> {:ok, centre}
          nil -> {:error, "#{inspect(name)} is no waypoint or place of #{known(state)}"}
        end
    end
  end

  defp known(%{wdf: nil, learned: nil}), do: "the robot's (it knows none yet)"
  defp known(%{wdf: %{file: file}}), do: file
  defp known(_state), do: "the learned map"

  ## Doors

  # the doors the robot knows: the WDF's open ones and the learned map's
  defp doors(state) do
    drawn =
      for d <- (state.wdf && state.wdf.doors) || [], not MapSet.member?(state.closed, d.name) do
        door(d.name, d.from, d.to)
      end

    learned =
      for d <- (state.learned && Map.values(state.learned.doors)) || [],
          do: door(d.name, d.from, d.to)

    drawn ++ learned
  end

  defp door(name, {x1, y1} = a, {x2, y2} = b) do
    %{
      name: name,
      jambs: {a, b},
      centre: {(x1 + x2) / 2, (y1 + y2) / 2},
      width: :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)
    }
  end

  # the first door the rest of the path crosses (its centre within half a
  # metre of the path), at least 0.4 m from the robot
  defp next_door(%{plan: %{path: _}, pose: {x, y, _}} = state) do
    path = remaining_path(state)
    indexed = Enum.with_index(path)

    state
    |> doors()
    |> Enum.flat_map(fn %{centre: {cx, cy} = c} = door ->
      near = Enum.find(indexed, fn {p, _} -> dist(p, c) < 0.5 end)

      if near && :math.sqrt((cx - x) ** 2 + (cy - y) ** 2) > 0.4,
        do: [{elem(near, 1), door}],
        else: []
    end)
    |> Enum.min_by(&elem(&1, 0), fn -> nil end)
    |> case do
      nil -> nil
      {_, door} -> door
    end
  end

  defp next_door(_state), do: nil

  # on the WDF's map only: the next door of the path, if the LPS holds
  # obstacle evidence across the middle of its opening while the robot is
  # near it (on a sensed map the shut door is in the map)
  defp shut_door(%{source: :sensed}), do: nil
  defp shut_door(%{lps: nil}), do: nil
  defp shut_door(%{plan: nil}), do: nil

  defp shut_door(state) do
    case next_door(state) do
      nil ->
        nil

      door ->
        {x, y, _} = state.pose
        {cx, cy} = door.centre
        d = :math.sqrt((cx - x) ** 2 + (cy - y) ** 2)
        if d < 3.0 and across(state, door) >= 3 and wdf_door?(state, door), do: door, else: nil
    end
  end

  defp wdf_door?(state, door), do: Enum.any?(state.wdf.doors, &(&1.name == door.name))

  # obstacle points within 0.1 m of the middle 60 % of the door's opening
  defp across(state, door) do
    {a, b} = door.jambs
    {p, q} = {lerp(a, b, 0.2), lerp(a, b, 0.8)}
    {ra, rb} = {to_frame(state.pose, p), to_frame(state.pose, q)}

    Enum.count(state.lps.evidence, fn {px, py, o, e} ->
      min(o, 1 - e) >= 0.5 and segment_distance({px, py}, ra, rb) < 0.1
    end)
  end

  ## Publishing

  defp publish(state) do
    plan = %{
      task: state.task,
      state: state.status,
      waypoint: state.target,
      goal: goal_point(state),
      heading: state.target && target_heading(state, state.target),
      docking: state.docking,
      path: remaining_path(state),
      door: door_to_cross(state),
      closed_doors: MapSet.to_list(state.closed),
      replans: state.replans,
      recoveries: state.recoveries,
      reached: Enum.reverse(state.reached),
      given_up: Enum.reverse(state.given_up),
      reason: state.reason,
      source: state.source,
      planning: state.planner.last,
      planned_at: state.planned_at
    }

    {:out, Tuples.keyed(Tuples.plan(state.robot, plan))}
  end

  defp goal_point(%{target: nil}), do: nil

  defp goal_point(state) do
    case goal(state, state.target) do
      {:ok, point} -> point
      {:error, _} -> nil
    end
  end

  defp remaining_path(%{plan: %{path: path}, pose: {x, y, _}}) do
    {_, i} =
      path
      |> Enum.with_index()
      |> Enum.min_by(fn {{px, py}, _} -> (px - x) ** 2 + (py - y) ** 2 end)

    Enum.drop(path, i)
  end

  defp remaining_path(_state), do: nil

  # Exploring on the sensed map, no door is given to cross: the path,
  # planned on what the sensors saw and kept clear of the jambs, goes
  # through the opening. The door behaviour crept through each door at
  # 0.1 m/s, a quarter of an exploration's time on generated buildings.
  defp door_to_cross(%{task: :explore, source: :sensed}), do: nil
  defp door_to_cross(%{plan: nil}), do: nil
  defp door_to_cross(%{pose: nil}), do: nil

  defp door_to_cross(state) do
    case next_door(state) do
      nil ->
        nil

      door ->
        # across the opening, from the robot's side to the other
        {x, y, _} = state.pose
        {cx, cy} = door.centre
        {{x1, y1}, {x2, y2}} = door.jambs
        {nx, ny} = {-(y2 - y1), x2 - x1}
        {nx, ny} = if nx * (cx - x) + ny * (cy - y) < 0, do: {-nx, -ny}, else: {nx, ny}
        door |> Map.delete(:jambs) |> Map.put(:heading, :math.atan2(ny, nx))
    end
  end

  ## Context

  defp robot_radius(context, params) do
    cond do
      is_number(params[:radius]) ->
        params[:radius]

      is_binary(context[:rdf]) ->
        case Description.load(context.rdf) do
          {:ok, d} -> d.footprint.radius
          {:error, message} -> raise ArgumentError, message
        end

      true ->
        0.2
    end
  end
end
