Code.require_file("support/nav_run.exs", __DIR__)

defmodule ThinkingCap.Bench.Nav do
  @moduledoc """
  `mix tc.bench nav [--map PATH.yaml ...] [--runs N] [--seed S] [--trace]`:
  autonomous navigation end to end on a map the robot is given. The
  simulated differential robot of `priv/examples/office_robot.rdf` (sonar
  ring, laser, odometry error on) runs the whole cognitive stack
  (perception, laser localization without beacons, blended fuzzy
  behaviours, planner/monitor) in lockstep with the simulator
  (`ThinkingCap.Sim.LockstepController`), as fast as possible, in each
  `map_server` map (default: nav2's `turtlebot3_world` and `warehouse`,
  `priv/maps/`), from N
  (default 50) start and goal pairs drawn with the seed from reachable
  free space.

  A run succeeds when the planner reports the task done (not given up)
  within a time limit (three times the optimal path at 0.2 m/s, plus 30 s)
  and the simulator's true pose is within 0.5 m of the goal. Collisions:
  runs in which the robot touched anything (a blocked step in the
  simulator: bumper contact or footprint overlap). Path ratio, over the
  successful runs: driven length (the true pose, sampled every 0.1 s,
  plus the straight line from where the robot stopped to the goal) over
  the A* path length on the grid inflated by the robot's radius alone,
  the shortest way a robot of its size could take (at the grid's
  resolution).

  Ends with `nav: runs=N success=K collisions=C path_ratio=R`.
  """

  alias ThinkingCap.Bench.NavRun
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim

  def run(args) do
    opts = NavRun.options(args, 50)
    tmp = NavRun.tmp_dir()
    {:ok, d} = Description.load(NavRun.rdf())
    radius = d.footprint.radius

    results =
      Enum.flat_map(opts.maps, fn yaml ->
        name = Path.basename(yaml, ".yaml")
        wdf = NavRun.write_wdf(tmp, name, yaml)
        {grid, tight} = NavRun.grids(wdf, radius)
        {:ok, world} = Sim.World.load(wdf)

        free? = fn cell ->
          Sim.World.free?(world, ThinkingCap.Navigation.Grid.centre(grid, cell), radius + 0.05)
        end

        rng = :rand.seed_s(:exsss, {opts.seed, 42, 1})
        {pairs, _} = NavRun.pairs(grid, tight, free?, opts.runs, rng)

        results =
          for {pair, i} <- Enum.with_index(pairs, 1) do
            r = NavRun.run(wdf, wdf, pair, seed: opts.seed * 1000 + i, modules: &modules/1)
            IO.puts(NavRun.line(name, i, r))
            r
          end

        print(name, results)
        results
      end)

    print("nav", results)
    File.rm_rf!(tmp)
  end

  defp modules(pair) do
    [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.MCL, [initial: pair.start, initial_sigma: {0.1, 0.05}]},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner: {ThinkingCap.Planner.Monitor, [task: {:go_to, pair.goal}], period: 0.5}
    ]
  end

  defp print(label, results) do
    s = NavRun.summary(results)

    IO.puts(
      "#{label}: runs=#{s.runs} success=#{s.success} collisions=#{s.collisions} " <>
        "path_ratio=#{NavRun.fmt(s.path_ratio)}"
    )
  end
end
