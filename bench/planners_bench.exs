defmodule ThinkingCap.Bench.Planners do
  @moduledoc """
  `mix tc.bench planners [--jobs J] [--every K] [--replans N] [--scattered S] [--seed X]`:
  the grid planners on Moving AI's `maze512-32-9` benchmark (512×512
  cells, corridors 32 cells wide, 8,010 problems up to 3,200 cells long).

  1. A* (`ThinkingCap.Navigation.AStar`) on every problem: the mean wall
     time of one plan and how many costs are within 1e-4 of the file's
     optimal lengths. One problem at a time by default (about 8 minutes);
     `--jobs J` runs J at once, each plan still timed on its own (so the
     times grow when the jobs compete for the cores and memory);
     `--every K` takes every K-th problem only, for a quick look.

  2. D* Lite replanning after a local change, on N long problems (default
     50: every 10th of the 500 longest). D* Lite plans the whole path; the
     robot advances a tenth of the way along it (`move_start/2`); then
     obstacles appear just ahead of it: of the cells within 2 cells of the
     path still ahead (the band), 1% are blocked, picked at random among
     the first 4% of the band from 3 cells ahead of the robot on (never
     the robot's cell or the goal). D* Lite's repair (`update_cells/2` and
     `plan/1`) is timed against A* from scratch from the robot's cell on
     the changed grid, and both costs must agree (within 1e-9).
     `replan_speedup` is the ratio of their mean times. Each problem runs
     in a process of its own, as in a planner module.

  3. For contrast, on S problems (default 5; 0 skips it): the same number
     of cells blocked at random anywhere along the band of the whole path,
     most of them far from the robot. A change near the goal changes the
     distance to the goal of every cell behind it, so D* Lite, which
     searches from the goal, has to repair most of what it had searched:
     it is slower there than A* from scratch.

  The summary line:

      planners: problems=… optimal=… astar_mean_us=… dstar_replan_us=… astar_replan_us=… replan_speedup=…
  """

  alias ThinkingCap.Navigation.{AStar, DStarLite, Grid, MovingAI}

  @data Path.expand("../test/data/movingai", __DIR__)
  @band 2

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args,
        strict: [
          jobs: :integer,
          every: :integer,
          replans: :integer,
          scattered: :integer,
          seed: :integer
        ]
      )

    jobs = opts[:jobs] || 1
    replans = opts[:replans] || 50
    scattered = opts[:scattered] || 5
    seed = opts[:seed] || 1

    {:ok, grid} = MovingAI.load_map(Path.join(@data, "maze512-32-9.map"))
    {:ok, problems} = MovingAI.load_scenarios(Path.join(@data, "maze512-32-9.map.scen"))

    IO.puts(
      "planners: maze512-32-9, #{length(problems)} problems, #{jobs} job(s), " <>
        "#{System.schedulers_online()} schedulers"
    )

    # 1. A* on every problem
    sample = Enum.take_every(problems, opts[:every] || 1)
    {wall_us, solutions} = :timer.tc(fn -> MovingAI.solve(grid, sample, jobs: jobs) end)
    optimal = Enum.count(solutions, & &1.optimal)
    astar_mean = mean(solutions, & &1.us)

    IO.puts(
      "  A*: #{optimal}/#{length(solutions)} optimal, mean #{fmt(astar_mean / 1000)} ms " <>
        "(#{round(mean(solutions, & &1.expanded))} cells expanded), " <>
        "#{fmt(wall_us / 1.0e6)} s wall"
    )

    for {label, group} <- by_length(solutions) do
      IO.puts(
        "    #{label}: mean #{fmt(mean(group, & &1.us) / 1000)} ms, " <>
          "#{round(mean(group, & &1.expanded))} expanded"
      )
    end

    for s <- solutions, not s.optimal do
      IO.puts("    not optimal: #{inspect(s.problem)}: #{inspect(s.cost)}")
    end

    # 2. D* Lite repairs after a local change
    long = problems |> Enum.sort_by(& &1.optimal_length, :desc) |> Enum.take(replans * 10)
    local = long |> Enum.take_every(10) |> Enum.map(&isolated(grid, &1, :local, seed))
    report("local change ahead of the robot", local)

    # 3. changes all along the path, for contrast
    if scattered > 0 do
      far = long |> Enum.take_every(div(length(long), scattered)) |> Enum.take(scattered)

      report(
        "the same changes scattered along the path",
        Enum.map(far, &isolated(grid, &1, :scattered, seed))
      )
    end

    dstar_us = mean(local, & &1.dstar_us)
    astar_us = mean(local, & &1.astar_us)

    IO.puts(
      "planners: problems=#{length(solutions)} optimal=#{optimal} " <>
        "astar_mean_us=#{round(astar_mean)} dstar_replan_us=#{round(dstar_us)} " <>
        "astar_replan_us=#{round(astar_us)} replan_speedup=#{fmt(astar_us / dstar_us)}"
    )
  end

  # each problem in a fresh process, as a planner module would run: its
  # garbage collections do not copy the benchmark's own data
  defp isolated(grid, p, where, seed) do
    Task.async(fn ->
      :rand.seed(:exsss, {seed, p.bucket, :erlang.phash2(p.start_xy)})
      replan(grid, p, where)
    end)
    |> Task.await(:infinity)
  end

  defp replan(grid, p, where) do
    state = DStarLite.new(grid, p.start, p.goal)
    {init_us, {:ok, path, state}} = :timer.tc(fn -> DStarLite.plan(state) end)
    initial = state.expanded

    # the robot advances a tenth of the way
    at = div(length(path), 10)
    robot = Enum.at(path, at)
    state = DStarLite.move_start(state, robot)
    ahead = Enum.drop(path, at)

    band =
      for {c, r} <- ahead,
          dc <- -@band..@band,
          dr <- -@band..@band,
          cell = {c + dc, r + dr},
          Grid.passable?(grid, cell),
          uniq: true,
          do: cell

    k = max(1, round(length(band) / 100))

    candidates =
      case where do
        :local ->
          near = MapSet.new(Enum.take(ahead, 3))

          band
          |> Enum.drop_while(&(not far_enough?(&1, near)))
          |> Enum.take(4 * k)

        :scattered ->
          band
      end

    blocked =
      candidates
      |> Enum.reject(&(&1 == robot or &1 == p.goal))
      |> Enum.take_random(k)
      |> Enum.map(&{&1, true})

    {dstar_us, {dstar_cost, state}} =
      :timer.tc(fn ->
        case state |> DStarLite.update_cells(blocked) |> DStarLite.plan() do
          {:ok, new_path, state} -> {AStar.cost(new_path), state}
          {:error, :no_path, state} -> {nil, state}
        end
      end)

    {astar_us, astar} = :timer.tc(fn -> AStar.plan(state.grid, robot, p.goal) end)

    {astar_cost, astar_expanded} =
      case astar do
        {:ok, %{cost: cost, expanded: n}} -> {cost, n}
        {:error, _} -> {nil, 0}
      end

    same =
      (dstar_cost == nil and astar_cost == nil) or
        (dstar_cost != nil and astar_cost != nil and abs(dstar_cost - astar_cost) < 1.0e-9)

    %{
      init_us: init_us,
      initial: initial,
      blocked: length(blocked),
      dstar_us: dstar_us,
      dstar_expanded: state.expanded,
      astar_us: astar_us,
      astar_expanded: astar_expanded,
      detour:
        if(astar_cost,
          do: astar_cost - (p.optimal_length - AStar.cost(Enum.take(path, at + 1))),
          else: nil
        ),
      same: same
    }
  end

  # a band cell at least 3 path cells ahead of the robot: not next to the first cells
  defp far_enough?({c, r}, near) do
    not Enum.any?(near, fn {nc, nr} -> abs(nc - c) <= @band and abs(nr - r) <= @band end)
  end

  defp report(label, runs) do
    n = length(runs)
    same = Enum.count(runs, & &1.same)
    detours = runs |> Enum.map(& &1.detour) |> Enum.reject(&is_nil/1)

    IO.puts(
      "  D* Lite, #{label} (#{n} problems, mean #{round(mean(runs, & &1.blocked))} cells blocked, " <>
        "paths #{fmt(mean(detours, & &1))} cells longer on average):"
    )

    IO.puts(
      "    initial plan #{fmt(mean(runs, & &1.init_us) / 1000)} ms " <>
        "(#{round(mean(runs, & &1.initial))} vertices); " <>
        "repair #{fmt(mean(runs, & &1.dstar_us) / 1000)} ms " <>
        "(#{round(mean(runs, & &1.dstar_expanded))} vertices) against A* from scratch " <>
        "#{fmt(mean(runs, & &1.astar_us) / 1000)} ms " <>
        "(#{round(mean(runs, & &1.astar_expanded))} cells): " <>
        "speedup #{fmt(mean(runs, & &1.astar_us) / mean(runs, & &1.dstar_us))}; " <>
        "same cost #{same}/#{n}"
    )
  end

  defp by_length(solutions) do
    solutions
    |> Enum.group_by(&min(div(&1.problem.bucket, 200), 3))
    |> Enum.sort()
    |> Enum.map(fn {b, group} ->
      {"buckets #{b * 200}-#{if b == 3, do: 800, else: b * 200 + 199} (#{length(group)})", group}
    end)
  end

  defp mean([], _f), do: 0.0
  defp mean(list, f), do: Enum.sum(Enum.map(list, f)) / length(list)

  defp fmt(x) when is_float(x), do: :erlang.float_to_binary(x, decimals: 2)
  defp fmt(x), do: to_string(x)
end
