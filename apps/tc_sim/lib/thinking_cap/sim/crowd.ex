defmodule ThinkingCap.Sim.Crowd do
  @moduledoc """
  Many walkers at once, drawn from a seed: each walks back and forth along
  a route of points in free space, every leg clear of walls for its disc.
  The result is the `:walkers` option of `ThinkingCap.Sim.start_link/1`:

      walkers = ThinkingCap.Sim.Crowd.walkers(world, count: 200, seed: 7)
      {:ok, sim} = ThinkingCap.Sim.start_link(world: world, walkers: walkers)

  The same world, options and seed give the same walkers.
  """

  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Sim.World

  @attempts 200

  @doc """
  `count` walkers (`:count`, required), ids `:w1`, `:w2`, ... Options:

    * `:seed` - integer (default 1);
    * `:points` - points of a route (default 3);
    * `:reach` - the longest leg, metres (default 10.0);
    * `:speed` - `{min, max}` m/s, each walker's drawn between (default
      `{0.6, 1.2}`);
    * `:radius` - metres (default 0.25);
    * `:area` - `{{x0, y0}, {x1, y1}}` to draw points in (default the
      world's bounds).

  Points are free for the disc with 0.1 m to spare (and known-free cells
  of the world's map, if it has one); legs are free all along. Raises
  `ArgumentError` naming the option for bad options, or when the world
  has no room.
  """
  @spec walkers(World.t(), keyword()) :: [{atom(), keyword()}]
  def walkers(%World{} = world, opts) do
    count = option(opts, :count, nil, &(is_integer(&1) and &1 >= 0))
    seed = option(opts, :seed, 1, &is_integer/1)
    points = option(opts, :points, 3, &(is_integer(&1) and &1 >= 2))
    reach = option(opts, :reach, 10.0, &(is_number(&1) and &1 > 0))
    radius = option(opts, :radius, 0.25, &(is_number(&1) and &1 > 0))

    {vmin, vmax} =
      option(opts, :speed, {0.6, 1.2}, fn
        {a, b} -> is_number(a) and is_number(b) and a > 0 and b >= a
        _ -> false
      end)

    area = option(opts, :area, world.bounds, &area?/1)
    spec = %{world: world, points: points, reach: reach, radius: radius, area: area}
    rng = :rand.seed_s(:exsss, {seed, 18, 200})

    {walkers, _} =
      Enum.map_reduce(1..count//1, {rng, []}, fn k, {rng, starts} ->
        {[start | _] = route, rng} = route(spec, starts, rng, 0)
        {u, rng} = :rand.uniform_s(rng)
        speed = vmin + u * (vmax - vmin)
        {{:"w#{k}", [route: route, speed: speed, radius: radius * 1.0]}, {rng, [start | starts]}}
      end)

    walkers
  end

  defp option(opts, key, default, valid?) do
    value = Keyword.get(opts, key, default)

    if value != nil and valid?.(value),
      do: value,
      else: raise(ArgumentError, "ThinkingCap.Sim.Crowd: #{key}: #{inspect(value)} is not valid")
  end

  defp area?({{x0, y0}, {x1, y1}}),
    do: Enum.all?([x0, y0, x1, y1], &is_number/1) and x1 > x0 and y1 > y0

  defp area?(_), do: false

  # a route of spec.points points, starting clear of the other walkers'
  # starts; a walker whose route cannot go on starts again
  defp route(_spec, _starts, _rng, tries) when tries > @attempts,
    do: raise(ArgumentError, "ThinkingCap.Sim.Crowd: no room for a walker's route in the world")

  defp route(spec, starts, rng, tries) do
    apart = 2 * spec.radius + 0.1

    case point(spec, rng, fn p -> Enum.all?(starts, &(dist(&1, p) > apart)) end, 0) do
      {nil, rng} ->
        route(spec, starts, rng, tries + 1)

      {start, rng} ->
        case legs(spec, [start], spec.points - 1, rng) do
          {nil, rng} -> route(spec, starts, rng, tries + 1)
          {points, rng} -> {Enum.reverse(points), rng}
        end
    end
  end

  defp legs(_spec, points, 0, rng), do: {points, rng}

  defp legs(spec, [prev | _] = points, n, rng) do
    near = fn p -> dist(p, prev) <= spec.reach and leg_free?(spec, prev, p) end

    case point(spec, rng, near, 0) do
      {nil, rng} -> {nil, rng}
      {p, rng} -> legs(spec, [p | points], n - 1, rng)
    end
  end

  defp point(_spec, rng, _ok?, tries) when tries >= @attempts, do: {nil, rng}

  defp point(spec, rng, ok?, tries) do
    {{x0, y0}, {x1, y1}} = spec.area
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    p = {x0 + u * (x1 - x0), y0 + v * (y1 - y0)}

    if free?(spec, p, 0.1) and ok?.(p),
      do: {p, rng},
      else: point(spec, rng, ok?, tries + 1)
  end

  defp free?(spec, {x, y} = p, spare) do
    known_free?(spec.world, p) and World.free?(spec.world, {x, y}, spec.radius + spare)
  end

  defp known_free?(%World{wdf: %{grid: %RosMap{} = grid}}, {x, y}) do
    {ox, oy, yaw} = grid.origin
    {c, s} = {:math.cos(yaw), :math.sin(yaw)}
    col = floor((c * (x - ox) + s * (y - oy)) / grid.resolution)
    row = floor((-s * (x - ox) + c * (y - oy)) / grid.resolution)

    col >= 0 and row >= 0 and col < grid.width and row < grid.height and
      RosMap.cell(grid, col, row) == 0
  end

  defp known_free?(_world, _p), do: true

  # the disc free at every 0.1 m of the leg
  defp leg_free?(spec, {ax, ay}, {bx, by} = b) do
    n = max(1, ceil(dist({ax, ay}, b) / 0.1))

    Enum.all?(0..n, fn k ->
      t = k / n
      free?(spec, {ax + t * (bx - ax), ay + t * (by - ay)}, 0.0)
    end)
  end

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
end
