Code.require_file("support/nav_run.exs", __DIR__)

defmodule ThinkingCap.Bench.NavUnknown do
  @moduledoc """
  `mix tc.bench nav_unknown [--map PATH.yaml ...] [--runs N] [--seed S] [--trace]`:
  as `mix tc.bench nav` (the robot is given the map), but the true world
  also holds 8 boxes the robot was not told about, up to three of them on
  the shortest path from start to goal (one 0.4 to 0.7 m square at 30, 50
  and 70 % of its length, where that is at least 1 m from the start and
  the goal, as every box) and the rest elsewhere in free space, and a person
  walking back and forth across the path's middle (`ThinkingCap.Sim`'s
  walkers), seen by every sensor. The stack adds the map
  builder (`ThinkingCap.Navigation.Mapper`, seeded with the given map) and
  plans on what it builds, repairing its plans with D* Lite.

  The optimal path is the shortest one in the true world, boxes
  included. `replan_speedup_live` is, over the replans made in the runs
  (plans again to the same goal: D* Lite's repairs, those after a jump
  of the start, and its new searches where too many cells changed for a
  repair), the mean time A* from scratch takes on the
  same grid over the mean time D* Lite took
  (`ThinkingCap.Navigation.PathPlanner`'s `compare: true`). Both times
  are the CPU time the searches took on their threads: on a machine
  shared with other programs, the wall clock also counts the time the
  operating system gave them, a few milliseconds at random that swamp
  a repair of a few hundred microseconds. The wall-clock means and their
  ratio are printed beside. `TC_DRAW=DIR` draws each run as `DIR/run_SEED.png`
  (1 cm a pixel: the true world, the learned map's occupied cells in
  orange, the shortest path before the boxes in blue, the true shortest
  one in teal, the path driven in red) and a frame each time the plan's
  length jumps by 0.9 m or more (the plan before in purple, after in
  green); `TC_DRAW_WINDOW=x0,x1,y0,y1` (metres, floats) draws only that
  window, at 0.5 cm a pixel. `TC_REPLANS=FILE` appends every replan's
  record (`ThinkingCap.Navigation.PathPlanner`'s `last`) to FILE.

  Ends with
  `nav_unknown: runs=N success=K collisions=C path_ratio=R replan_speedup_live=X`.
  """

  alias ThinkingCap.Bench.NavRun
  alias ThinkingCap.Navigation.{AStar, Grid}
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim

  @boxes 8
  @boxes_on_path [0.3, 0.5, 0.7]

  def run(args) do
    opts = NavRun.options(args, 20)
    tmp = NavRun.tmp_dir()
    {:ok, d} = Description.load(NavRun.rdf())
    radius = d.footprint.radius

    results =
      Enum.flat_map(opts.maps, fn yaml ->
        name = Path.basename(yaml, ".yaml")
        robot_wdf = NavRun.write_wdf(tmp, name, yaml)
        {grid, tight} = NavRun.grids(robot_wdf, radius)
        {:ok, world} = Sim.World.load(robot_wdf)
        free? = fn cell -> Sim.World.free?(world, Grid.centre(grid, cell), radius + 0.05) end
        rng = :rand.seed_s(:exsss, {opts.seed, 43, 1})
        {pairs, rng} = NavRun.pairs(grid, tight, free?, opts.runs, rng)

        {results, _} =
          pairs
          |> Enum.with_index(1)
          |> Enum.map_reduce(rng, fn {pair, i}, rng ->
            {truth, pair, reachable, rng} =
              place_boxes(tmp, "#{name}_#{i}", yaml, grid, radius, pair, rng, 10)

            r =
              if reachable do
                NavRun.run(truth, robot_wdf, pair,
                  seed: opts.seed * 1000 + i,
                  modules: &modules/1,
                  walkers: walkers(simworld_of(truth), pair)
                )
              end

            if r, do: IO.puts(NavRun.line(name, i, r))
            {r, rng}
          end)

        results = Enum.reject(results, &is_nil/1)
        print(name, results, dump: true)
        results
      end)

    print("nav_unknown", results)
    File.rm_rf!(tmp)
  end

  defp modules(pair) do
    [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.MCL,
         [initial: pair.start, initial_sigma: {0.1, 0.05}] ++ NavRun.env_params("TC_MCL")},
      mapper: {ThinkingCap.Navigation.Mapper, NavRun.env_params("TC_MAPPER")},
      control: {ThinkingCap.Control.Blender, NavRun.env_params("TC_CONTROL"), period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor, [task: {:go_to, pair.goal}, compare: true], period: 0.5}
    ]
  end

  # a person walking across the path's middle, as far as the free space
  # there goes each way (up to 3 m), back and forth
  defp walkers(world, pair) do
    path = List.to_tuple(pair.path)
    n = tuple_size(path)
    {x, y} = elem(path, div(n, 2))
    {ax, ay} = elem(path, max(div(n, 2) - 3, 0))
    {bx, by} = elem(path, min(div(n, 2) + 3, n - 1))
    len = max(:math.sqrt((bx - ax) ** 2 + (by - ay) ** 2), 1.0e-9)
    {nx, ny} = {-(by - ay) / len, (bx - ax) / len}
    reach = fn sign -> free_reach(world, {x, y}, {sign * nx, sign * ny}, 0.0) end
    {a, b} = {reach.(1), reach.(-1)}

    if a + b >= 1.0 do
      [[:person, [route: [{x + nx * a, y + ny * a}, {x - nx * b, y - ny * b}], speed: 0.8]]]
    else
      []
    end
  end

  defp free_reach(world, {x, y} = p, {dx, dy} = d, s) do
    next = s + 0.1

    if next <= 3.0 and Sim.World.free?(world, {x + dx * next, y + dy * next}, 0.3),
      do: free_reach(world, p, d, next),
      else: s
  end

  # boxes that leave the goal reachable (drawn again if they do not)
  defp place_boxes(tmp, name, yaml, grid, radius, pair, rng, tries) do
    {boxes, rng} = boxes(grid, pair, rng)
    truth = NavRun.write_wdf(tmp, name, yaml, boxes)

    case true_optimal(truth, radius, pair) do
      {pair, true} -> {truth, pair, true, rng}
      {pair, false} when tries <= 1 -> {truth, pair, false, rng}
      _ -> place_boxes(tmp, name, yaml, grid, radius, pair, rng, tries - 1)
    end
  end

  # eight boxes, squares of 0.4 to 0.7 m, at least 1 m from the start and
  # the goal: one at each of 30, 50 and 70 % of the path's length that is
  # that far, the rest elsewhere in free space
  defp boxes(grid, pair, rng) do
    path = List.to_tuple(pair.path)
    n = tuple_size(path)
    {sx, sy, _} = pair.start
    far? = fn {x, y} -> dist({x, y}, {sx, sy}) > 1.0 and dist({x, y}, pair.goal) > 1.0 end

    {on_path, rng} =
      Enum.map_reduce(@boxes_on_path, rng, fn f, rng ->
        {x, y} = elem(path, min(n - 1, round(f * (n - 1))))
        {size, rng} = size(rng)
        {if(far?.({x, y}), do: square({x, y}, size)), rng}
      end)

    on_path = Enum.reject(on_path, &is_nil/1)
    elsewhere(grid, far?, @boxes - length(on_path), rng, on_path, 10_000)
  end

  defp elsewhere(_grid, _far?, 0, rng, boxes, _tries), do: {boxes, rng}

  defp elsewhere(_grid, _far?, _left, _rng, _boxes, 0),
    do: raise("nav_unknown: no free cell 1 m from both the start and the goal for a box")

  defp elsewhere(grid, far?, left, rng, boxes, tries) do
    {cell, rng} = NavRun.free_cell(grid, rng)
    {size, rng} = size(rng)
    centre = Grid.centre(grid, cell)

    if far?.(centre),
      do: elsewhere(grid, far?, left - 1, rng, boxes ++ [square(centre, size)], tries - 1),
      else: elsewhere(grid, far?, left, rng, boxes, tries - 1)
  end

  defp size(rng) do
    {u, rng} = :rand.uniform_s(rng)
    {0.4 + 0.3 * u, rng}
  end

  defp square({x, y}, s) do
    h = s / 2
    [{x - h, y - h}, {x + h, y - h}, {x + h, y + h}, {x - h, y + h}]
  end

  # the shortest collision-free path in the true world, boxes included
  defp true_optimal(truth, radius, pair) do
    {grid, tight} = NavRun.grids(truth, radius)
    {sx, sy, _} = pair.start

    with {:ok, %{path: cells}} <-
           AStar.plan(grid, Grid.cell_of(grid, {sx, sy}), Grid.cell_of(grid, pair.goal)),
         {:ok, %{cost: cost}} <-
           AStar.plan(tight, Grid.cell_of(tight, {sx, sy}), Grid.cell_of(tight, pair.goal)) do
      # the way with the planner's margin, drawn by TC_DRAW
      true_path = Enum.map(cells, &Grid.centre(grid, &1))
      {Map.merge(pair, %{optimal: cost * tight.resolution, true_path: true_path}), true}
    else
      _ -> {pair, false}
    end
  end

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)

  defp simworld_of(wdf) do
    {:ok, world} = Sim.World.load(wdf)
    world
  end

  # `dump: true` (once per map, not again for the total) appends the
  # replans to TC_REPLANS's file
  defp print(label, results, opts \\ []) do
    s = NavRun.summary(results)

    repairs =
      for r <- results,
          p <- r.replans,
          p.kind in [:repair, :restart, :jump],
          Map.has_key?(p, :astar_us),
          do: p

    restarts = Enum.count(repairs, &(&1.kind == :restart))
    jumps = Enum.count(repairs, &(&1.kind == :jump))

    if (path = System.get_env("TC_REPLANS")) && opts[:dump],
      do: File.write!(path, Enum.map(repairs, &(inspect(&1) <> "\n")), [:append])

    astar = NavRun.mean(Enum.map(repairs, & &1.astar_cpu_us))
    dstar = NavRun.mean(Enum.map(repairs, & &1.cpu_us))
    astar_wall = NavRun.mean(Enum.map(repairs, & &1.astar_us))
    dstar_wall = NavRun.mean(Enum.map(repairs, & &1.us))

    IO.puts(
      "#{label}: runs=#{s.runs} success=#{s.success} collisions=#{s.collisions} " <>
        "path_ratio=#{NavRun.fmt(s.path_ratio)} replan_speedup_live=#{ratio(astar, dstar)}" <>
        " (#{length(repairs)} replans, #{jumps} after a jump, #{restarts} new searches; " <>
        "#{round(NavRun.mean(Enum.map(repairs, & &1.changed)))} cells changed; CPU time: " <>
        "A* #{round(astar)} us, D* Lite #{round(dstar)} us; wall clock: " <>
        "A* #{round(astar_wall)} us, D* Lite #{round(dstar_wall)} us, " <>
        "ratio #{ratio(astar_wall, dstar_wall)})"
    )
  end

  defp ratio(a, b), do: NavRun.fmt(if b > 0, do: a / b, else: 0.0)
end
