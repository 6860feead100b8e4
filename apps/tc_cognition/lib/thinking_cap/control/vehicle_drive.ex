defmodule ThinkingCap.Control.VehicleDrive do
  @moduledoc """
  The control cycle of a car-like robot (tricycle, Ackermann: forklifts,
  tugs), as a `ThinkingCap.Module` in place of `ThinkingCap.Control.Blender`:
  it drives kinematically feasible paths to the plan's goal and docks.

      control: [
        module: ThinkingCap.Control.VehicleDrive,
        activity: :periodic, period: 0.1, deadline: 0.08
      ]

  For each new goal of the plan (`{:plan, robot, %{goal:, heading:}}`
  from `ThinkingCap.Planner.Monitor`) it plans a path of forward and
  reverse arcs (`ThinkingCap.Control.Vehicle.Planner`, hybrid A*) on the
  WDF's grid inflated by the robot's radius, and follows it with
  regulated pure pursuit (`ThinkingCap.Control.Vehicle.Tracker`),
  stopping at each change of direction.

  **Docking.** When the goal has a heading and the RDF a `docking:`
  section, the path ends with a straight final leg of `approach` metres
  along the goal's heading, driven forwards or in reverse
  (`direction:`) at the docking `speed`; the search only has to reach
  that line. At the end of the leg the robot stops; if it is outside the
  docking tolerances it plans again (backing out and coming in anew), at
  most `dock_attempts` times.

  **Safety.** Before each command it checks the LPS: if an obstacle would
  come within `clearance` of the robot's disc along the next stretch of
  the arc it is about to drive (its stopping distance plus 0.3 m, no
  farther than the path goes), it stops instead, and plans again after
  `blocked_replan` seconds of standing. A robot off its path by more than
  `max_deviation` plans again from where it is.

  ## Blackboard

  Reads `{:pose, robot, _}`, `{:plan, robot, _}`, `{:lps, robot, _}`.
  Writes `{:drive, robot, %{command: {:velocity, v, w}}}` (key
  `{:drive, robot}`) every cycle, and
  `{:vehicle, robot, %{state:, path:, goal:, docking_error:}}` (key
  `{:vehicle, robot}`): `state` is `:idle`, `:planning`, `:driving`,
  `:blocked` (an obstacle in the way), `:no_path` (the search failed; it
  tries again every 2 s), `:settling` (stopped at the end of the path,
  for a second before it checks the docking tolerances), `:docked` or
  `:dock_failed`. It stands still
  while the plan's state is one of `stop_states`.

  ## Params

  `resolution: 0.1` (m, the planning grid), `margin: 0.12` (m beyond the
  radius: the grid's cells and the LPS's sectors are coarse), `clearance:
  0.0` (m beyond the radius for the safety check), `lookahead: 0.8` (m), `max_deviation:
  0.6` (m), `blocked_replan: 4.0` (s), `dock_attempts: 3`,
  `max_expansions: 30_000`, `stop_states: [:idle, :done, :failed,
  :blocked, :waiting]`. The RDF (required) gives the drive, its limits,
  the radius and the docking section; the WDF (required) the map.
  """
  use ThinkingCap.Module
  require Logger

  alias ThinkingCap.Control.Steering
  alias ThinkingCap.Control.Vehicle.{Planner, Tracker}
  alias ThinkingCap.Navigation.Maps
  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Robot.{Description, Kinematics}
  alias ThinkingCap.Tuples
  require Tuples
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @defaults [
    resolution: 0.1,
    margin: 0.12,
    clearance: 0.0,
    lookahead: 0.8,
    max_deviation: 0.6,
    blocked_replan: 4.0,
    dock_attempts: 3,
    max_expansions: 30_000,
    stop_states: [:idle, :done, :failed, :blocked, :waiting]
  ]

  @stop {:velocity, 0.0, 0.0}

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, if(is_map(params), do: Map.to_list(params), else: params))
    description = description!(context)
    wdf = wdf!(context)
    radius = description.footprint.radius
    limits = Kinematics.limits(description.kinematics)

    grid =
      wdf
      |> Maps.grid_from_wdf(grid_opts(wdf, params))
      |> Maps.inflate(radius + params[:margin])

    state = %{
      robot: context.robot,
      params: params,
      grid: grid,
      radius: radius,
      curvature: Steering.max_curvature(description.kinematics),
      limits: limits,
      docking: description.docking,
      pose: nil,
      plan: nil,
      lps: nil,
      time: 0.0,
      goal: nil,
      tracker: nil,
      status: :idle,
      attempts: 0,
      retry_at: nil,
      blocked_since: nil,
      settle_since: nil,
      docking_error: nil
    }

    {[
       subscribe: Tuples.pose(context.robot),
       subscribe: Tuples.plan(context.robot),
       subscribe: Tuples.lps(context.robot)
     ], state}
  end

  defp description!(%{rdf: rdf} = context) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, d} -> d
      {:error, message} -> raise ArgumentError, "#{inspect(context[:name])}: rdf: #{message}"
    end
  end

  defp description!(context),
    do: raise(ArgumentError, "#{inspect(context[:name])}: VehicleDrive needs the ADF's rdf:")

  defp wdf!(%{wdf: path} = context) when is_binary(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, wdf} ->
        wdf

      {:error, errors} ->
        raise ArgumentError,
              "#{inspect(context[:name])}: #{ThinkingCap.Config.format_errors(errors)}"
    end
  end

  defp wdf!(context),
    do: raise(ArgumentError, "#{inspect(context[:name])}: VehicleDrive needs the ADF's wdf:")

  # an occupancy map brings its own resolution
  defp grid_opts(%{grid: nil}, params), do: [resolution: params[:resolution]]
  defp grid_opts(_wdf, _params), do: []

  @impl true
  def handle_tuple(Tuples.pose(robot, %{pose: {_, _, _} = pose}), %{robot: robot} = state),
    do: {[], %{state | pose: pose}}

  def handle_tuple(Tuples.plan(robot, plan), %{robot: robot} = state) when is_map(plan),
    do: {[], %{state | plan: plan}}

  def handle_tuple(Tuples.lps(robot, %LPS{} = lps), %{robot: robot} = state),
    do: {[], %{state | lps: lps}}

  def handle_tuple(_tuple, state), do: {[], state}

  @impl true
  def handle_cycle(release, state) do
    state = %{state | time: release.scheduled_ns / 1.0e9}
    {command, state} = control(state)
    robot = state.robot

    info = %{
      state: state.status,
      goal: state.goal,
      path: if(state.tracker, do: Tracker.points(state.tracker), else: nil),
      docking_error: state.docking_error
    }

    {[
       out: Tuples.keyed(Tuples.drive(robot, %{command: command})),
       out: Tuples.keyed(Tuples.vehicle(robot, info))
     ], state}
  end

  ## Control

  defp control(%{pose: nil} = state), do: {@stop, state}
  defp control(%{plan: nil} = state), do: {@stop, state}

  defp control(state) do
    goal = goal(state.plan)

    cond do
      finishing_leg?(state, goal) ->
        drive(state)

      Map.get(state.plan, :state) in state.params[:stop_states] or goal == nil ->
        status = if state.status == :docked, do: :docked, else: :idle
        {@stop, %{state | status: status, tracker: nil, goal: goal}}

      goal != state.goal ->
        control(new_goal(state, goal))

      state.status in [:docked, :dock_failed] ->
        {@stop, state}

      state.status == :settling ->
        if state.time - state.settle_since >= 1.0, do: arrived(state), else: {@stop, state}

      state.tracker == nil ->
        if state.retry_at == nil or state.time >= state.retry_at,
          do: control_planned(plan_path(state)),
          else: {@stop, state}

      true ->
        drive(state)
    end
  end

  # the monitor saw the dock reached: drive the last centimetres of the
  # final leg to its end, slowing down, rather than stop short
  defp finishing_leg?(%{tracker: %Tracker{} = t, status: :driving} = state, goal) do
    Map.get(state.plan, :state) == :done and goal == state.goal and docking?(state) and
      t.index == tuple_size(t.segments) - 1 and t.remaining < 0.3
  end

  defp finishing_leg?(_state, _goal), do: false

  defp control_planned(%{tracker: nil} = state), do: {@stop, state}
  defp control_planned(state), do: drive(state)

  defp new_goal(state, goal),
    do: %{
      state
      | goal: goal,
        tracker: nil,
        status: :planning,
        attempts: 0,
        retry_at: nil,
        docking_error: nil
    }

  # {x, y, heading or nil}
  defp goal(plan) do
    case Map.get(plan, :goal) do
      {x, y} -> {x * 1.0, y * 1.0, Map.get(plan, :heading)}
      _ -> nil
    end
  end

  defp drive(state) do
    {x, y, _} = state.pose

    cond do
      Tracker.deviation(state.tracker, {x, y}) > state.params[:max_deviation] ->
        Logger.debug("#{inspect(state.robot)}: off the path; planning again")
        {@stop, %{state | tracker: nil}}

      true ->
        case Tracker.step(state.tracker, state.pose, tracker_opts(state)) do
          # stand still a moment, then see how it stands
          {:done, tracker} ->
            {@stop, %{state | tracker: tracker, status: :settling, settle_since: state.time}}

          {:drive, twist, tracker} ->
            guarded(%{state | tracker: tracker}, twist)
        end
    end
  end

  defp tracker_opts(state) do
    final = if state.docking && docking?(state), do: state.docking.speed, else: 0.3

    [
      max_curvature: state.curvature,
      max_speed: state.limits.max_speed * 0.8,
      max_turn_rate: state.limits.max_turn_rate,
      accel: state.limits.max_acceleration * 0.5,
      lookahead: state.params[:lookahead],
      final_speed: min(final, state.limits.max_speed)
    ]
  end

  defp docking?(%{goal: {_, _, heading}, docking: docking}), do: heading != nil and docking != nil

  # at the end of the path, standing: docked, or again
  defp arrived(state) do
    {error, ok} = docking_error(state)
    state = %{state | docking_error: error}

    cond do
      ok ->
        {@stop, %{state | status: :docked}}

      state.attempts + 1 >= state.params[:dock_attempts] ->
        Logger.info("#{inspect(state.robot)}: could not dock at #{inspect(state.goal)}")
        {@stop, %{state | status: :dock_failed}}

      true ->
        {@stop, %{state | tracker: nil, attempts: state.attempts + 1}}
    end
  end

  defp docking_error(%{goal: {gx, gy, heading}, pose: {x, y, th}} = state) do
    d = :math.sqrt((gx - x) ** 2 + (gy - y) ** 2)
    dth = if heading, do: abs(normalize_angle(th - heading)), else: 0.0

    {tol, htol} =
      case state.docking do
        %{position_tolerance: p, heading_tolerance: h} when heading != nil -> {p, h}
        _ -> {0.3, :infinity}
      end

    {%{position: d, heading: dth}, d <= tol and dth <= htol}
  end

  # stop short of what the LPS shows on the way
  defp guarded(state, {v, w} = twist) do
    if clear?(state, v, w) do
      {{:velocity, v, w}, %{state | status: :driving, blocked_since: nil}}
    else
      since = state.blocked_since || state.time

      if state.time - since >= state.params[:blocked_replan],
        do: {@stop, %{state | status: :blocked, blocked_since: nil, tracker: nil}},
        else: {@stop, %{state | status: :blocked, blocked_since: since}}
    end
    |> then(fn {command, state} -> {if(twist == {0.0, 0.0}, do: @stop, else: command), state} end)
  end

  defp clear?(%{lps: nil}, _v, _w), do: true

  defp clear?(state, v, w) do
    lps = state.lps
    # the stopping distance and a margin, no farther than the path goes
    reach =
      min(
        v * v / (2 * state.limits.max_acceleration) + 0.3,
        state.tracker.remaining + 0.05
      )
      |> max(0.05)

    kappa = if abs(v) > 1.0e-6, do: w / v, else: 0.0
    dir = if v < 0, do: -1.0, else: 1.0
    limit = state.radius + state.params[:clearance]

    points =
      for i <- 0..(lps.n - 1),
          d = elem(lps.bins, i),
          d < lps.range,
          a = LPS.sector_angle(lps, i),
          do: {d * :math.cos(a), d * :math.sin(a)}

    steps = max(1, ceil(reach / 0.1))

    Enum.all?(1..steps, fn k ->
      {px, py, _} = Kinematics.integrate({0.0, 0.0, 0.0}, {dir, dir * kappa}, k * reach / steps)
      Enum.all?(points, fn {ox, oy} -> (ox - px) ** 2 + (oy - py) ** 2 >= limit * limit end)
    end)
  end

  ## Planning

  defp plan_path(state) do
    {gx, gy, heading} = state.goal
    docking = docking?(state)

    {target, final, line} =
      if docking do
        a = state.docking.approach
        dir = if state.docking.direction == :reverse, do: -1, else: 1
        {c, s} = {:math.cos(heading), :math.sin(heading)}
        # the start of the final leg, and a stretch farther out that is as good
        {px, py} = {gx - dir * a * c, gy - dir * a * s}
        far = {gx - dir * (a + 1.5) * c, gy - dir * (a + 1.5) * s}
        near = {gx - dir * max(a - 0.8, 0.6) * c, gy - dir * max(a - 0.8, 0.6) * s}
        {{px, py, heading}, {dir, {px, py}, {gx, gy}}, {near, far}}
      else
        {{gx, gy, nil}, nil, nil}
      end

    # a drive that turns on the spot plans with a 0.2 m turning radius
    k = if state.curvature == :infinity, do: 5.0, else: state.curvature

    opts = [max_curvature: k, max_expansions: state.params[:max_expansions]]

    case search(state, target, line, opts) do
      {:ok, segments} ->
        segments = segments ++ final_leg(final, segments, state.pose)
        %{state | tracker: Tracker.new(segments), status: :driving, retry_at: nil}

      {:error, reason} ->
        Logger.info(
          "#{inspect(state.robot)}: no feasible path to #{inspect(state.goal)}: #{reason}"
        )

        %{state | tracker: nil, status: :no_path, retry_at: state.time + 2.0}
    end
  end

  # onto the final leg within 0.15 m and 0.15 rad; failing that (a dock
  # in a tight corner), within 0.25 m and 0.25 rad: the leg corrects the rest
  defp search(state, target, nil, opts), do: Planner.plan(state.grid, state.pose, target, opts)

  defp search(state, target, {near, far}, opts) do
    strict = [line: {near, far, 0.15}, heading_tolerance: 0.15] ++ opts

    case Planner.plan(state.grid, state.pose, target, strict) do
      {:error, :too_hard} ->
        relaxed = [line: {near, far, 0.25}, heading_tolerance: 0.25] ++ opts
        Planner.plan(state.grid, state.pose, target, relaxed)

      result ->
        result
    end
  end

  # the straight leg into the dock, from where the search ended (projected
  # on the line) to the dock, a point every 5 cm
  defp final_leg(nil, _segments, _pose), do: []

  defp final_leg({dir, {px, py}, {gx, gy}}, segments, pose) do
    {sx, sy} =
      case List.last(segments) do
        %{poses: [_ | _] = poses} -> poses |> List.last() |> then(fn {x, y, _} -> {x, y} end)
        _ -> pose |> then(fn {x, y, _} -> {x, y} end)
      end

    {ex, ey} = {gx - px, gy - py}
    len = :math.sqrt(ex * ex + ey * ey)
    {ux, uy} = {ex / len, ey / len}
    # the search's end projected on the leg (it may be farther out than its
    # start, or a little past it)
    t0 = min((sx - px) * ux + (sy - py) * uy, len - 0.6)
    n = max(2, ceil((len - t0) / 0.05))

    points =
      for k <- 0..n,
          do: {px + ux * (t0 + (len - t0) * k / n), py + uy * (t0 + (len - t0) * k / n)}

    [%{direction: dir, points: points}]
  end
end
