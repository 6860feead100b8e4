defmodule ThinkingCap.Bench.Nav do
  @moduledoc """
  `mix tc.bench nav [--runs N] [--worlds turtlebot3_world,warehouse]`:
  autonomous navigation end to end. The simulated differential robot of
  `priv/examples/office_robot.rdf` (sonar ring, laser, beacon sensor,
  odometry error on) runs the whole cognitive stack (perception, EKF
  localization with beacons, blended fuzzy behaviours, planner/monitor) in
  lockstep with the simulator (`ThinkingCap.Sim.LockstepController`), as
  fast as possible, in nav2's `turtlebot3_world` and `warehouse` maps with
  beacons placed at random in free space (one per 25 m², at least 16),
  from N (default 50) random reachable start and goal pairs each.

  Start and goal pairs are reachable on the grid the planner uses (inflated
  by the robot's radius and the planner's margin). A run succeeds when the
  planner reports the task done (not given up: `:failed`) within a time
  limit (three times the optimal path at 0.2 m/s, plus 30 s) and the
  simulator's true pose is within 0.5 m of the goal. Collisions: runs in
  which the robot touched anything (a blocked step in the simulator). Path
  ratio, over the successful runs: driven length (the true pose, sampled
  every 0.1 s, plus the straight line from where the robot stopped to the
  goal) over the A* path length on the grid inflated by the robot's
  radius alone, the shortest way a robot of its size could take (at the
  grid's resolution).
  """

  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.LockstepController
  alias ThinkingCap.Navigation.{AStar, Grid, Maps}
  alias ThinkingCap.Testing.Lockstep

  @root Path.expand("..", __DIR__)
  @maps Path.expand("../priv/maps", __DIR__)

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args, strict: [runs: :integer, worlds: :string, trace: :boolean])

    runs = opts[:runs] || 50
    Process.put(:trace, opts[:trace] || false)
    worlds = String.split(opts[:worlds] || "turtlebot3_world,warehouse", ",")
    rdf = Path.join(@root, "priv/examples/office_robot.rdf")
    tmp = Path.join(System.tmp_dir!(), "tc_nav_bench_#{System.unique_integer([:positive])}")
    File.mkdir_p!(tmp)

    results =
      Enum.flat_map(worlds, fn world ->
        wdf = write_world(tmp, world)
        r = world_runs(world, wdf, rdf, runs)
        summary(world, r)
        r
      end)

    summary("nav", results)
    File.rm_rf!(tmp)
  end

  defp summary(label, results) do
    n = length(results)
    ok = Enum.filter(results, & &1.success)
    collisions = Enum.count(results, &(&1.blocked > 0))
    ratio = mean(Enum.map(ok, &(&1.driven / max(&1.optimal, 1.0e-6))))
    time = mean(Enum.map(ok, & &1.time))

    IO.puts(
      "#{label}: runs=#{n} success=#{length(ok)} collisions=#{collisions} " <>
        "path_ratio=#{fmt(ratio)} mean_time_s=#{fmt(time)}"
    )
  end

  defp mean([]), do: 0.0
  defp mean(xs), do: Enum.sum(xs) / length(xs)

  # the map, plus beacons spread over its free space
  defp write_world(dir, world) do
    yaml = Path.join(@maps, "#{world}.yaml")
    {:ok, map} = ThinkingCap.Config.RosMap.load(yaml)
    rng = :rand.seed_s(:exsss, {7, 7, 7})
    beacons = beacons(map, beacon_count(map), rng)

    data = [
      name: world,
      map: [yaml: yaml],
      beacons: for({{x, y}, i} <- Enum.with_index(beacons), do: [name: :"b#{i}", at: {x, y}])
    ]

    path = Path.join(dir, "#{world}.wdf")
    File.write!(path, inspect(data, limit: :infinity))
    path
  end

  # one beacon per 25 m² of free space (at least 16), as an installation
  # would place them for two or more in sight almost everywhere: 16 in
  # turtlebot3_world (20 m²), 51 in the warehouse (1,280 m²)
  defp beacon_count(map) do
    free =
      for c <- 0..(map.width - 1),
          r <- 0..(map.height - 1),
          ThinkingCap.Config.RosMap.cell(map, c, r) == 0,
          reduce: 0,
          do: (n -> n + 1)

    max(16, round(free * map.resolution * map.resolution / 25))
  end

  defp beacons(map, n, rng) do
    {ox, oy, _} = map.origin

    Stream.unfold(rng, fn rng ->
      {u, rng} = :rand.uniform_s(rng)
      {v, rng} = :rand.uniform_s(rng)
      {{floor(u * map.width), floor(v * map.height)}, rng}
    end)
    |> Stream.filter(fn {c, r} -> ThinkingCap.Config.RosMap.cell(map, c, r) == 0 end)
    |> Stream.map(fn {c, r} ->
      {ox + (c + 0.5) * map.resolution, oy + (r + 0.5) * map.resolution}
    end)
    |> Enum.take(n)
  end

  defp world_runs(world, wdf_path, rdf, runs) do
    wdf = ThinkingCap.Config.read!(wdf_path)
    {:ok, d} = ThinkingCap.Robot.Description.load(rdf)
    map = Maps.grid_from_wdf(wdf, [])
    # the planner's grid (ThinkingCap.Planner.Monitor's default margin)
    grid = Maps.inflate(map, d.footprint.radius + 0.08)
    tight = Maps.inflate(map, d.footprint.radius)
    {:ok, simworld} = Sim.World.from_wdf(wdf)
    rng = :rand.seed_s(:exsss, {42, 1, 1})

    free? = fn cell ->
      Sim.World.free?(simworld, Grid.centre(grid, cell), d.footprint.radius + 0.05)
    end

    {pairs, _} = pairs(grid, tight, free?, runs, rng, [])

    pairs
    |> Enum.with_index(1)
    |> Enum.map(fn {{start, goal, optimal}, i} ->
      # a world holds its robots' bodies: one per run
      {:ok, simworld} = Sim.World.from_wdf(wdf)
      r = one_run(simworld, wdf_path, rdf, start, goal, optimal, i)

      IO.puts(
        "  #{world} #{i}: #{if r.success, do: "ok  ", else: "FAIL"} #{fmt(r.time)} s, " <>
          "driven #{fmt(r.driven)} m / optimal #{fmt(optimal)} m, blocked #{r.blocked}" <>
          if(r.success,
            do: "",
            else:
              " (plan #{r.state}, #{fmt(r.gap)} m from the goal, " <>
                "localization off by #{if r.pose_error, do: fmt(r.pose_error), else: "-"} m)"
          )
      )

      r
    end)
  end

  # random start/goal pairs, reachable on the planner's grid, with a path
  # at least 2 m long; the optimal length is the path on the tight grid
  defp pairs(_grid, _tight, _free?, 0, rng, acc), do: {Enum.reverse(acc), rng}

  defp pairs(grid, tight, free?, n, rng, acc) do
    {a, rng} = free_cell(grid, rng)
    {b, rng} = free_cell(grid, rng)

    with true <- free?.(a),
         {:ok, %{cost: cost}} when cost * grid.resolution >= 2.0 <- AStar.plan(grid, a, b),
         {:ok, %{cost: optimal}} <- AStar.plan(tight, a, b) do
      {th, rng} = :rand.uniform_s(rng)
      start = Grid.centre(grid, a) |> Tuple.append((th - 0.5) * 2 * :math.pi())

      pairs(grid, tight, free?, n - 1, rng, [
        {start, Grid.centre(grid, b), optimal * tight.resolution} | acc
      ])
    else
      _ -> pairs(grid, tight, free?, n, rng, acc)
    end
  end

  defp free_cell(grid, rng) do
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    cell = {floor(u * grid.width), floor(v * grid.height)}
    if Grid.passable?(grid, cell), do: {cell, rng}, else: free_cell(grid, rng)
  end

  defp one_run(world, wdf, rdf, start, goal, optimal, seed) do
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false, step: 0.05, seed: seed)
    {sx, sy, sth} = start

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.Localizer, [initial: start, initial_sigma: {0.1, 0.05}]},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner: {ThinkingCap.Planner.Monitor, [task: {:go_to, goal}], period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :nav,
        rdf: rdf,
        at: {sx, sy, sth},
        controller: {LockstepController, modules: modules, rdf: rdf, wdf: wdf}
      )

    limit = optimal / 0.2 * 3 + 30
    {time, driven, last} = drive(sim, limit, {sx, sy}, 0.0, 0)
    status = Sim.status(sim)
    {:ok, cstate} = Sim.controller_state(sim, :nav)
    plan = Lockstep.latest(cstate.lock, {:plan, :nav, :_})
    estimate = Lockstep.latest(cstate.lock, {:pose, :nav, :_})
    GenServer.stop(sim)
    {gx, gy} = goal
    gap = :math.sqrt((elem(last, 0) - gx) ** 2 + (elem(last, 1) - gy) ** 2)
    at_goal = gap <= 0.5
    done = match?({:plan, _, %{state: :done}}, plan) and at_goal
    state = if plan, do: elem(plan, 2).state, else: nil

    %{
      success: done,
      state: state,
      at_goal: at_goal,
      gap: gap,
      pose_error: pose_error(estimate, last),
      time: time,
      # the planner stops within its tolerance of the goal: the rest of the
      # way counts as driven, so that stopping short does not look shorter
      driven: driven + gap,
      optimal: optimal,
      blocked: status.blocked
    }
  end

  # how far the localizer's estimate is from the true position
  defp pose_error({:pose, _, %{pose: {ex, ey, _}} = p}, {x, y}) do
    if Process.get(:trace), do: IO.inspect(p[:covariance], label: "covariance at the end")
    :math.sqrt((ex - x) ** 2 + (ey - y) ** 2)
  end

  defp pose_error(_estimate, _true), do: nil

  # runs 0.1 s at a time (summing the true pose's steps), looking at the
  # plan every half second, until it is done or failed or time is up
  defp drive(sim, limit, last, driven, step) do
    :ok = Sim.run_for(sim, 0.1)
    {:ok, {x, y, _}} = Sim.pose(sim, :nav)
    {lx, ly} = last
    driven = driven + :math.sqrt((x - lx) ** 2 + (y - ly) ** 2)
    time = Sim.time(sim)

    if rem(step, 5) == 4 do
      {:ok, cstate} = Sim.controller_state(sim, :nav)
      plan = Lockstep.latest(cstate.lock, {:plan, :nav, :_})
      if Process.get(:trace), do: trace(time, {x, y}, plan, cstate.lock)

      case plan do
        {:plan, _, %{state: s}} when s in [:done, :failed] -> {time, driven, {x, y}}
        _ when time >= limit -> {time, driven, {x, y}}
        _ -> drive(sim, limit, {x, y}, driven, step + 1)
      end
    else
      drive(sim, limit, {x, y}, driven, step + 1)
    end
  end

  defp trace(time, {x, y}, plan, lock) do
    activation =
      case Lockstep.latest(lock, {:activation, :nav, :_}) do
        {:activation, _, a} -> for {b, v} <- a, v >= 0.05, do: "#{b}=#{fmt(v)}"
        nil -> []
      end

    {:drive, _, %{command: command}} =
      Lockstep.latest(lock, {:drive, :nav, :_}) || {:drive, nil, %{command: nil}}

    state = if plan, do: elem(plan, 2).state, else: nil

    IO.puts(
      "    t=#{fmt(time)} (#{fmt(x)}, #{fmt(y)}) #{state} #{inspect(command)} #{Enum.join(activation, " ")}"
    )
  end

  defp fmt(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)
end
