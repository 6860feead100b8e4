defmodule ThinkingCap.Control.Vehicle.Planner do
  @moduledoc """
  Kinematically feasible paths for car-like robots: a hybrid A* search
  (Dolgov et al.) over poses, on a planning grid inflated by the robot's
  radius (`ThinkingCap.Navigation.Grid`; a pose is free when its cell is).

  From a pose the search drives arcs of `step` metres, forwards and in
  reverse, at five curvatures from full left to full right lock (the
  drive's `max_curvature`), checking the grid every half cell. Poses are
  merged by cell of `key_resolution` and heading bin. Costs: length, more
  in reverse (`reverse_cost`), a `switch_cost` for each change of
  direction and a little for steering. The heuristic is the larger of the
  straight distance and the obstacle-aware distance on the grid
  (`distance_field/2`, computed once per goal), weighted by `weight`.

  A **goal** is a pose `{x, y, theta}` (theta `nil`: any heading) reached
  within `tolerance` metres and `heading_tolerance` radians. For docking,
  give `line: {a, b, lateral}`: then any pose whose heading is within
  `heading_tolerance` of the goal's and that lies within `lateral` metres
  of the segment from point `a` to point `b` is a goal too (the straight
  final leg, which a tracker then follows in).

  The path comes back as segments of constant direction, each a list of
  poses about every `grid resolution` metres.
  """

  import Bitwise, only: [<<<: 2]

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Robot.Kinematics
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @typedoc "A world pose, m and rad."
  @type pose :: {float(), float(), float()}

  @typedoc "A stretch of path driven one way: 1 forwards, -1 in reverse."
  @type segment :: %{direction: 1 | -1, poses: [pose()]}

  @typedoc "An obstacle-aware distance to the goal per grid cell (m), as a tuple of rows."
  @type field :: %{grid: Grid.t(), dist: tuple()}

  @defaults [
    step: 0.5,
    headings: 48,
    key_resolution: 0.25,
    tolerance: 0.2,
    heading_tolerance: 0.15,
    reverse_cost: 1.5,
    switch_cost: 2.0,
    steer_cost: 0.05,
    weight: 2.0,
    max_expansions: 30_000,
    reverse: true
  ]

  @doc """
  Plans from `start` to `goal`. Options: `max_curvature:` (1/m, required),
  `field:` (a `distance_field/2` to the goal's point, computed if absent),
  `line:`, and the defaults `#{inspect(@defaults)}`.

  Returns `{:ok, segments}`, or `{:error, reason}` with reason
  `:start_blocked`, `:goal_blocked`, `:unreachable` or `:too_hard` (the
  search ran out of expansions).
  """
  @spec plan(Grid.t(), pose(), {float(), float(), float() | nil}, keyword()) ::
          {:ok, [segment()]} | {:error, atom()}
  def plan(%Grid{} = grid, {sx, sy, _} = start, {gx, gy, _} = goal, opts) do
    o = Keyword.merge(@defaults, opts) |> Map.new()
    k = Keyword.fetch!(opts, :max_curvature)

    cond do
      not free?(grid, sx, sy) ->
        {:error, :start_blocked}

      not free?(grid, gx, gy) ->
        {:error, :goal_blocked}

      true ->
        field = o[:field] || distance_field(grid, {gx, gy})
        o = Map.merge(o, %{field: field, k: k, goal: goal, grid: grid})
        search(Map.put(o, :primitives, primitives(o)), start)
    end
  end

  @doc """
  The distance (m) from every free cell of `grid` to the cell of `point`,
  8-connected around obstacles (Dijkstra); `:infinity` where unreachable.
  """
  @spec distance_field(Grid.t(), {number(), number()}) :: field()
  def distance_field(%Grid{width: w, height: h} = grid, point) do
    {c, r} = Grid.cell_of(grid, point)
    dist = :atomics.new(w * h, [])
    inf = 1 <<< 62
    for i <- 1..(w * h), do: :atomics.put(dist, i, inf)
    res = grid.resolution

    if Grid.passable?(grid, {c, r}) do
      :atomics.put(dist, r * w + c + 1, 0)
      dijkstra(grid, dist, :gb_sets.singleton({0, c, r}))
    end

    # millimetres in the atomics, metres out
    rows =
      for row <- 0..(h - 1) do
        List.to_tuple(
          for col <- 0..(w - 1) do
            v = :atomics.get(dist, row * w + col + 1)
            if v >= inf, do: :infinity, else: v / 1000 * res
          end
        )
      end

    %{grid: grid, dist: List.to_tuple(rows)}
  end

  # costs in thousandths of a cell: 1000 straight, 1414 diagonal
  @moves [
    {1, 0, 1000},
    {-1, 0, 1000},
    {0, 1, 1000},
    {0, -1, 1000},
    {1, 1, 1414},
    {1, -1, 1414},
    {-1, 1, 1414},
    {-1, -1, 1414}
  ]

  defp dijkstra(grid, dist, open) do
    if :gb_sets.is_empty(open) do
      :ok
    else
      {{d, c, r}, open} = :gb_sets.take_smallest(open)
      w = grid.width

      if d > :atomics.get(dist, r * w + c + 1) do
        dijkstra(grid, dist, open)
      else
        open =
          Enum.reduce(@moves, open, fn {dc, dr, cost}, open ->
            n = {c + dc, r + dr}
            nd = d + cost

            if Grid.passable?(grid, n) and
                 (dc == 0 or dr == 0 or
                    (Grid.passable?(grid, {c + dc, r}) and Grid.passable?(grid, {c, r + dr}))) and
                 nd < :atomics.get(dist, (r + dr) * w + c + dc + 1) do
              :atomics.put(dist, (r + dr) * w + c + dc + 1, nd)
              :gb_sets.add({nd, c + dc, r + dr}, open)
            else
              open
            end
          end)

        dijkstra(grid, dist, open)
      end
    end
  end

  @doc "The distance of a field at a world point (m), `:infinity` outside or where unreachable."
  @spec field_distance(field(), {number(), number()}) :: float() | :infinity
  def field_distance(%{grid: grid, dist: dist}, point) do
    {c, r} = Grid.cell_of(grid, point)

    if Grid.inside?(grid, {c, r}),
      do: elem(elem(dist, r), c),
      else: :infinity
  end

  ## Search

  defp search(o, {sx, sy, sth}) do
    start = {sx * 1.0, sy * 1.0, normalize_angle(sth)}
    key = key(o, start)
    nodes = %{key => %{pose: start, g: 0.0, parent: nil, direction: 0, arc: []}}
    open = :gb_sets.singleton({h(o, start), 0, key})
    expand(o, open, nodes, MapSet.new(), 0)
  end

  defp expand(o, open, nodes, closed, n) do
    cond do
      :gb_sets.is_empty(open) ->
        {:error, :unreachable}

      n >= o.max_expansions ->
        {:error, :too_hard}

      true ->
        {{_f, _tie, key}, open} = :gb_sets.take_smallest(open)

        if MapSet.member?(closed, key) do
          expand(o, open, nodes, closed, n)
        else
          node = Map.fetch!(nodes, key)

          if goal?(o, node.pose) do
            {:ok, segments(nodes, key)}
          else
            closed = MapSet.put(closed, key)
            {open, nodes} = successors(o, node, key, open, nodes, closed, n)
            expand(o, open, nodes, closed, n + 1)
          end
        end
    end
  end

  defp successors(o, node, key, open, nodes, closed, n) do
    for {dir, kappa, offsets} <- o.primitives, reduce: {open, nodes} do
      {open, nodes} ->
        case arc(o, node.pose, offsets) do
          nil ->
            {open, nodes}

          {pose, samples} ->
            nkey = key(o, pose)

            if MapSet.member?(closed, nkey) do
              {open, nodes}
            else
              g = node.g + cost(o, node.direction, dir, kappa)

              case nodes do
                %{^nkey => %{g: old}} when old <= g ->
                  {open, nodes}

                _ ->
                  f = g + o.weight * h(o, pose)

                  nodes =
                    Map.put(nodes, nkey, %{
                      pose: pose,
                      g: g,
                      parent: key,
                      direction: dir,
                      arc: samples
                    })

                  {:gb_sets.add({f, n * 10 + length(samples), nkey}, open), nodes}
              end
            end
        end
    end
  end

  defp cost(o, previous, dir, kappa) do
    length = o.step * if(dir < 0, do: o.reverse_cost, else: 1.0)
    switch = if previous != 0 and previous != dir, do: o.switch_cost, else: 0.0
    length + switch + o.steer_cost * o.step * abs(kappa) / o.k
  end

  # the arcs from {0, 0, 0}: direction, curvature and the poses along
  # them, a sample about every cell
  defp primitives(o) do
    directions = if o.reverse, do: [1, -1], else: [1]
    n = max(1, ceil(o.step / o.grid.resolution))

    for dir <- directions, kappa <- [-o.k, -o.k / 2, 0.0, o.k / 2, o.k] do
      offsets =
        for i <- 1..n,
            do: Kinematics.integrate({0.0, 0.0, 0.0}, {dir * 1.0, dir * kappa}, i * o.step / n)

      {dir, kappa, offsets}
    end
  end

  # the arc moved to `pose`: its end pose and its samples, or nil if one hits
  defp arc(o, {x, y, th}, offsets) do
    {c, s} = {:math.cos(th), :math.sin(th)}

    Enum.reduce_while(offsets, [], fn {dx, dy, dth}, acc ->
      {px, py} = {x + c * dx - s * dy, y + s * dx + c * dy}

      if free?(o.grid, px, py),
        do: {:cont, [{px, py, normalize_angle(th + dth)} | acc]},
        else: {:halt, nil}
    end)
    |> case do
      nil -> nil
      [last | _] = acc -> {last, Enum.reverse(acc)}
    end
  end

  defp free?(grid, x, y), do: Grid.passable?(grid, Grid.cell_of(grid, {x, y}))

  defp key(o, {x, y, th}) do
    bins = o.headings
    bin = rem(round((th + :math.pi()) / (2 * :math.pi()) * bins), bins)
    {floor(x / o.key_resolution), floor(y / o.key_resolution), bin}
  end

  # the distance around obstacles, and at least the arc a turn to the
  # goal's heading takes at the tightest curvature
  defp h(o, {x, y, th}) do
    case field_distance(o.field, {x, y}) do
      :infinity ->
        1.0e9

      d ->
        case o.goal do
          {_, _, nil} -> d
          {_, _, gth} -> max(d, abs(normalize_angle(th - gth)) / o.k)
        end
    end
  end

  ## Goal

  defp goal?(o, {x, y, th}) do
    {gx, gy, gth} = o.goal
    d = :math.sqrt((gx - x) ** 2 + (gy - y) ** 2)
    heading_ok = gth == nil or abs(normalize_angle(th - gth)) <= o.heading_tolerance

    cond do
      not heading_ok -> false
      d <= o.tolerance -> true
      gth == nil -> false
      true -> on_line?(o, {x, y}, gth)
    end
  end

  defp on_line?(%{line: {{ax, ay}, {bx, by}, lateral}}, {x, y}, _gth) do
    {ex, ey} = {bx - ax, by - ay}
    l2 = ex * ex + ey * ey
    t = if l2 > 0, do: ((x - ax) * ex + (y - ay) * ey) / l2, else: 0.0
    across = abs((x - ax) * ey - (y - ay) * ex) / max(:math.sqrt(l2), 1.0e-9)
    t >= 0 and t <= 1 and across <= lateral
  end

  defp on_line?(_o, _point, _gth), do: false

  ## Path

  defp segments(nodes, key) do
    key
    |> Stream.unfold(fn
      nil -> nil
      k -> {Map.fetch!(nodes, k), Map.fetch!(nodes, k).parent}
    end)
    |> Enum.reverse()
    |> Enum.drop(1)
    |> Enum.chunk_by(& &1.direction)
    |> Enum.map(fn [first | _] = chunk ->
      %{direction: first.direction, poses: Enum.flat_map(chunk, & &1.arc)}
    end)
  end
end
