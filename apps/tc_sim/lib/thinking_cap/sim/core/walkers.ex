defmodule ThinkingCap.Sim.Core.Walkers do
  @moduledoc false
  # One step of the walkers: people (discs) walking routes of points at
  # their speed, back and forth (or round, `loop: true`). They step one
  # after the other in order of id, each seeing the robots where they now
  # stand and the walkers before it where they moved; one waits while its
  # next step would come within 0.05 m of a robot or another walker. The
  # discs sit in a grid of buckets as wide as the largest contact
  # distance, so a walker looks only at its 3 x 3 buckets: the step is
  # linear in robots + walkers.

  @gap 0.05

  @doc """
  Steps every walker (`%{id => walker}`) by `dt` seconds among the robots,
  given as `{x, y, radius}`.
  """
  @spec step(%{term() => map()}, [{float(), float(), float()}], float()) :: %{term() => map()}
  def step(walkers, _robots, _dt) when map_size(walkers) == 0, do: walkers

  def step(walkers, robots, dt) do
    robots = for {x, y, r} <- robots, do: {:robot, x, y, r}

    rmax = fn list -> Enum.reduce(list, 0.0, &max(elem(&1, 3), &2)) end
    wmax = walkers |> Map.values() |> Enum.reduce(0.0, &max(&1.radius, &2))
    h = rmax.(robots) + wmax + @gap
    h = max(h, wmax + wmax + @gap)

    discs = robots ++ for {id, %{at: {x, y}} = w} <- walkers, do: {{:walker, id}, x, y, w.radius}
    grid = Enum.reduce(discs, %{}, fn {_, x, y, _} = d, g -> put(g, cell(x, y, h), d) end)

    {walkers, _grid} =
      walkers
      |> Enum.sort()
      |> Enum.reduce({walkers, grid}, fn {id, w}, {walkers, grid} ->
        moved = step_walker(w, id, grid, h, dt)

        grid =
          if moved.at == w.at,
            do: grid,
            else: grid |> delete(w.at, id, h) |> insert(moved, id, h)

        {Map.put(walkers, id, moved), grid}
      end)

    walkers
  end

  defp cell(x, y, h), do: {floor(x / h), floor(y / h)}

  defp put(grid, cell, disc), do: Map.update(grid, cell, [disc], &[disc | &1])

  defp delete(grid, {x, y}, id, h) do
    Map.update!(grid, cell(x, y, h), fn discs ->
      Enum.reject(discs, &match?({{:walker, ^id}, _, _, _}, &1))
    end)
  end

  defp insert(grid, %{at: {x, y}, radius: r}, id, h),
    do: put(grid, cell(x, y, h), {{:walker, id}, x, y, r})

  defp step_walker(w, id, grid, h, dt) do
    {x, y} = w.at
    {tx, ty} = elem(w.route, w.leg)
    d = :math.sqrt((tx - x) ** 2 + (ty - y) ** 2)
    step = w.speed * dt

    if d <= step do
      next_leg(%{w | at: {tx, ty}})
    else
      next = {x + (tx - x) * step / d, y + (ty - y) * step / d}
      if clear?(next, w, id, grid, h), do: %{w | at: next}, else: w
    end
  end

  defp next_leg(%{leg: leg, dir: dir, route: route} = w) do
    n = tuple_size(route)

    cond do
      w.loop -> %{w | leg: rem(leg + 1, n)}
      leg + dir >= 0 and leg + dir < n -> %{w | leg: leg + dir}
      true -> %{w | leg: leg - dir, dir: -dir}
    end
  end

  defp clear?({x, y}, w, id, grid, h) do
    {cx, cy} = cell(x, y, h)

    Enum.all?(
      for(i <- -1..1, j <- -1..1, d <- Map.get(grid, {cx + i, cy + j}, []), do: d),
      fn
        {{:walker, ^id}, _, _, _} -> true
        {_, bx, by, r} -> (bx - x) ** 2 + (by - y) ** 2 > (r + w.radius + @gap) ** 2
      end
    )
  end
end
