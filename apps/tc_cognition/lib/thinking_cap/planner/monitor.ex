defmodule ThinkingCap.Planner.Monitor do
  @moduledoc """
  The Planner/Monitor as an ADF module (periodic): turns a task into
  plans and supervises their execution.

      planner: [module: ThinkingCap.Planner.Monitor, activity: :periodic, period: 0.5,
                params: [task: {:patrol, [:lab_bench, :desk_a, :dock]}]]

  Tasks (param `task:`, or later a `{:task, robot, %{task: task}}` tuple):
  `{:go_to, waypoint}`, `{:visit, [waypoint]}`, `{:patrol, [waypoint]}`
  (visits for ever) and `:idle`. Waypoints are the WDF's names, or
  `{x, y}` points.

  **Planning.** A route over the topological map of the WDF (places and
  the doors between them, `ThinkingCap.Navigation.Topology`, closed doors
  left out), refined by A* (`ThinkingCap.Navigation.AStar`) on the WDF's
  grid inflated by the robot's radius, from the estimated pose
  (`{:pose, robot, _}`, from the localizer).

  **Monitoring**, every cycle: a waypoint within `tolerance` is reached
  and the next one taken; a robot that makes no progress for
  `stuck_after` seconds gets a new plan, and after `max_replans` the
  waypoint is given up (a task that gave up any of its waypoints ends
  `:failed`, not `:done`); a door on the route seen shut in the LPS
  (`{:lps, robot, _}`) is marked closed,
  and the route is replanned around it, or the task waits (state
  `:blocked`) and tries again after `retry_after` seconds. A door counts
  as shut when the LPS holds obstacle evidence (at least three points)
  across the middle of its opening while the robot is within 3 m.

  **Published** as `{:plan, robot, %{task:, state:, waypoint:, goal:, path:,
  door:, closed_doors:, replans:, reached:, given_up:}}` (latest value):
  `state` is `:waiting` (no pose yet), `:moving`, `:blocked`, `:done` (every
  waypoint reached), `:failed` (the task ended with waypoints given up) or
  `:idle`;
  `path` the rest of the metric path (world points); `door` the next door
  to cross (`%{name:, centre:, width:, heading:}`, heading across the
  opening in the direction of travel). Doors seen shut are also published as
  `{:door, name, %{open: false, stamp: t}}`.
  """
  use ThinkingCap.Module
  require Logger

  alias ThinkingCap.Navigation.{AStar, Grid, Maps, Topology}
  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Robot.Description

  @defaults [
    tolerance: 0.35,
    stuck_after: 12.0,
    max_replans: 3,
    retry_after: 10.0,
    resolution: nil,
    margin: 0.08
  ]

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, if(is_map(params), do: Map.to_list(params), else: params))
    wdf = read_wdf!(context)
    radius = robot_radius(context, params)

    state = %{
      robot: context.robot,
      params: params,
      wdf: wdf,
      radius: radius,
      topology: Topology.from_wdf(wdf),
      closed: wdf.doors |> Enum.reject(& &1.open) |> MapSet.new(& &1.name),
      grid: nil,
      pose: nil,
      lps: nil,
      time: 0.0,
      task: :idle,
      queue: [],
      target: nil,
      plan: nil,
      status: :idle,
      reached: [],
      given_up: [],
      replans: 0,
      progress: nil,
      blocked_at: nil
    }

    state =
      state
      |> rebuild_grid()
      |> set_task(Keyword.get(params, :task, :idle))
      |> resume(Map.get(context, :handoff))

    {[
       subscribe: {:pose, context.robot, :_},
       subscribe: {:lps, context.robot, :_},
       subscribe: {:task, context.robot, :_}
     ], state}
  end

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
    state |> Map.merge(Map.put(handoff, :status, status)) |> rebuild_grid()
  end

  defp resume(state, _handoff), do: state

  @impl true
  def handle_tuple({:pose, robot, %{pose: pose}}, %{robot: robot} = state),
    do: {[], %{state | pose: pose}}

  def handle_tuple({:lps, robot, %LPS{} = lps}, %{robot: robot} = state),
    do: {[], %{state | lps: lps}}

  def handle_tuple({:task, robot, %{task: task}}, %{robot: robot} = state),
    do: {[], set_task(state, task)}

  def handle_tuple(_tuple, state), do: {[], state}

  @impl true
  def handle_cycle(release, state) do
    state = %{state | time: release.scheduled_ns / 1.0e9}
    {actions, state} = step(state)
    {actions ++ [publish(state)], state}
  end

  ## Tasks

  defp set_task(state, task) do
    queue =
      case task do
        {:go_to, wp} -> [wp]
        {:visit, wps} when is_list(wps) -> wps
        {:patrol, wps} when is_list(wps) and wps != [] -> wps
        :idle -> []
        other -> raise ArgumentError, "unknown task #{inspect(other)}"
      end

    %{
      state
      | task: task,
        queue: queue,
        target: nil,
        plan: nil,
        reached: [],
        given_up: [],
        replans: 0
    }
    |> Map.put(:status, if(queue == [], do: :idle, else: :waiting))
  end

  ## Monitoring

  defp step(%{pose: nil} = state), do: {[], state}
  defp step(%{status: status} = state) when status in [:idle, :done, :failed], do: {[], state}

  # resumed from a handoff with a waypoint under way: plan to it from here
  defp step(%{status: :waiting, target: target, plan: nil} = state) when target != nil,
    do: {[], plan(state)}

  defp step(%{target: nil, queue: [], given_up: []} = state), do: {[], %{state | status: :done}}
  defp step(%{target: nil, queue: []} = state), do: {[], %{state | status: :failed}}

  defp step(%{target: nil} = state) do
    [next | rest] = state.queue
    queue = if match?({:patrol, _}, state.task), do: rest ++ [next], else: rest
    state = %{state | target: next, queue: queue, replans: 0}
    {[], plan(state)}
  end

  defp step(%{status: :blocked} = state) do
    if state.time - state.blocked_at >= state.params[:retry_after] do
      # doors open again: forget what was seen shut, try again
      state = %{state | closed: initially_closed(state)} |> rebuild_grid()
      {[], plan(state)}
    else
      {[], state}
    end
  end

  defp step(state) do
    {x, y, _} = state.pose
    {tx, ty} = target_point(state, state.target)
    distance = :math.sqrt((tx - x) ** 2 + (ty - y) ** 2)
    {to_go, state} = to_go(state, distance)

    cond do
      distance <= state.params[:tolerance] ->
        state = %{state | reached: [state.target | state.reached], target: nil, plan: nil}
        step(state)

      door = shut_door(state) ->
        Logger.info("#{inspect(state.robot)}: door #{door.name} is shut; replanning")
        state = %{state | closed: MapSet.put(state.closed, door.name)} |> rebuild_grid()
        seen = {{:door, door.name, %{open: false, stamp: state.time}}, [key: {:door, door.name}]}
        {[out: seen], plan(state)}

      stuck?(state, to_go) ->
        if state.replans >= state.params[:max_replans] do
          Logger.info("#{inspect(state.robot)}: giving up #{inspect(state.target)}")
          step(%{state | given_up: [state.target | state.given_up], target: nil, plan: nil})
        else
          {[], plan(%{state | replans: state.replans + 1})}
        end

      true ->
        {[], %{state | progress: progress(state.progress, to_go, state.time)}}
    end
  end

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

  # the best distance to the target so far, and when it was reached
  defp progress({best, _since}, distance, time) when distance < best - 0.2, do: {distance, time}
  defp progress(nil, distance, time), do: {distance, time}
  defp progress(p, _distance, _time), do: p

  defp stuck?(%{progress: nil}, _distance), do: false

  defp stuck?(%{progress: {best, since}} = state, distance),
    do: distance >= best - 0.2 and state.time - since > state.params[:stuck_after]

  ## Planning

  defp plan(state) do
    goal = target_point(state, state.target)
    {x, y, _} = state.pose

    with {:ok, route} <- route(state, {x, y}, goal),
         {:ok, path} <- metric_path(state, {x, y}, goal) do
      length = path_length(path)
      plan = %{route: route, path: path, length: length, s: 0.0}
      %{state | plan: plan, status: :moving, progress: {length, state.time}}
    else
      {:error, reason} ->
        Logger.info(
          "#{inspect(state.robot)}: no plan to #{inspect(state.target)}: #{inspect(reason)}"
        )

        %{state | plan: nil, status: :blocked, blocked_at: state.time}
    end
  end

  defp route(state, from, to) do
    t = state.topology

    case {Topology.place_of(t, from), Topology.place_of(t, to)} do
      {nil, _} -> {:ok, []}
      {_, nil} -> {:ok, []}
      {a, b} -> Topology.route(t, a, b, closed: MapSet.to_list(state.closed))
    end
  end

  defp metric_path(state, from, to) do
    case AStar.plan_world(
           state.grid,
           nearest_free(state.grid, from),
           nearest_free(state.grid, to)
         ) do
      {:ok, %{path: path}} -> {:ok, simplify(state.grid, path) ++ [to]}
      {:error, reason} -> {:error, reason}
    end
  end

  # the point itself, or the nearest free cell's centre (a pose can sit
  # inside the inflated margin of a wall)
  defp nearest_free(grid, point) do
    {col, row} = Grid.cell_of(grid, point)

    if Grid.passable?(grid, {col, row}) do
      point
    else
      Enum.find_value(1..20, point, fn r ->
        cells = for dc <- -r..r, dr <- -r..r, max(abs(dc), abs(dr)) == r, do: {col + dc, row + dr}

        case Enum.filter(cells, &Grid.passable?(grid, &1)) do
          [] ->
            nil

          free ->
            Grid.centre(grid, Enum.min_by(free, fn {c, w} -> (c - col) ** 2 + (w - row) ** 2 end))
        end
      end)
    end
  end

  # every 8th point, and the corners
  defp simplify(_grid, path) when length(path) <= 2, do: path

  defp simplify(_grid, path) do
    path
    |> Enum.with_index()
    |> Enum.filter(fn {_p, i} -> rem(i, 8) == 0 end)
    |> Enum.map(&elem(&1, 0))
  end

  defp rebuild_grid(state) do
    # an imported occupancy map sets the resolution; 5 cm otherwise
    resolution = state.params[:resolution] || if(state.wdf.grid, do: nil, else: 0.05)
    opts = [closed: MapSet.to_list(state.closed)]
    opts = if resolution, do: [{:resolution, resolution} | opts], else: opts
    grid = Maps.grid_from_wdf(state.wdf, opts)

    %{state | grid: Maps.inflate(grid, state.radius + state.params[:margin])}
  end

  defp initially_closed(state),
    do: state.wdf.doors |> Enum.reject(& &1.open) |> MapSet.new(& &1.name)

  ## Doors

  # the next door of the route, if the LPS holds obstacle evidence across
  # the middle of its opening while the robot is near it
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
        if d < 3.0 and across(state, door) >= 3, do: door, else: nil
    end
  end

  # obstacle points within 0.1 m of the middle 60 % of the door's opening
  defp across(state, door) do
    {a, b} = door.jambs
    {p, q} = {lerp(a, b, 0.2), lerp(a, b, 0.8)}
    {ra, rb} = {to_robot(state.pose, p), to_robot(state.pose, q)}

    Enum.count(state.lps.evidence, fn {px, py, o, e} ->
      min(o, 1 - e) >= 0.5 and segment_distance({px, py}, ra, rb) < 0.1
    end)
  end

  defp lerp({x1, y1}, {x2, y2}, t), do: {x1 + t * (x2 - x1), y1 + t * (y2 - y1)}

  defp to_robot({x, y, th}, {px, py}) do
    {c, s} = {:math.cos(th), :math.sin(th)}
    {dx, dy} = {px - x, py - y}
    {c * dx + s * dy, -s * dx + c * dy}
  end

  defp segment_distance({x, y}, {ax, ay}, {bx, by}) do
    {ex, ey} = {bx - ax, by - ay}
    u = max(0.0, min(1.0, ((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey)))
    :math.sqrt((ax + u * ex - x) ** 2 + (ay + u * ey - y) ** 2)
  end

  defp next_door(%{plan: %{route: route}} = state) do
    {x, y, _} = state.pose

    route
    |> Enum.map(& &1.via_door)
    |> Enum.reject(&is_nil/1)
    |> Enum.map(&door_info(state, &1))
    |> Enum.find(fn %{centre: {cx, cy}} -> :math.sqrt((cx - x) ** 2 + (cy - y) ** 2) > 0.4 end)
  end

  defp door_info(state, name) do
    d = Enum.find(state.wdf.doors, &(&1.name == name))
    {{x1, y1}, {x2, y2}} = {d.from, d.to}

    %{
      name: name,
      jambs: {d.from, d.to},
      centre: {(x1 + x2) / 2, (y1 + y2) / 2},
      width: :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)
    }
  end

  ## Publishing

  defp publish(state) do
    plan = %{
      task: state.task,
      state: state.status,
      waypoint: state.target,
      goal: state.target && target_point(state, state.target),
      path: remaining_path(state),
      door: door_to_cross(state),
      closed_doors: MapSet.to_list(state.closed),
      replans: state.replans,
      reached: Enum.reverse(state.reached),
      given_up: Enum.reverse(state.given_up)
    }

    {:out, {{:plan, state.robot, plan}, [key: {:plan, state.robot}]}}
  end

  defp remaining_path(%{plan: %{path: path}, pose: {x, y, _}}) do
    {_, i} =
      path
      |> Enum.with_index()
      |> Enum.min_by(fn {{px, py}, _} -> (px - x) ** 2 + (py - y) ** 2 end)

    Enum.drop(path, i)
  end

  defp remaining_path(_state), do: nil

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

  defp target_point(_state, {x, y}) when is_number(x) and is_number(y), do: {x * 1.0, y * 1.0}

  defp target_point(state, name) when is_atom(name) do
    case Enum.find(state.wdf.waypoints, &(&1.name == name)) do
      %{at: {x, y}} -> {x * 1.0, y * 1.0}
      %{at: {x, y, _}} -> {x * 1.0, y * 1.0}
      nil -> raise ArgumentError, "no waypoint #{inspect(name)} in #{state.wdf.file}"
    end
  end

  ## Context

  defp read_wdf!(%{wdf: path}) when is_binary(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, wdf} -> wdf
      {:error, errors} -> raise ArgumentError, ThinkingCap.Config.format_errors(errors)
    end
  end

  defp read_wdf!(context),
    do: raise(ArgumentError, "#{inspect(context.name)}: the planner needs the ADF's wdf:")

  defp robot_radius(%{rdf: rdf}, params) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, d} -> d.footprint.radius
      {:error, message} -> raise ArgumentError, message
    end
    |> then(&Keyword.get(params, :radius, &1))
  end

  defp robot_radius(_context, params), do: Keyword.get(params, :radius, 0.2)
end
