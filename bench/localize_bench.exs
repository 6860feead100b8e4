Code.require_file("support/nav_run.exs", __DIR__)

defmodule ThinkingCap.Bench.Localize do
  @moduledoc """
  `mix tc.bench localize [--map PATH.yaml ...] [--runs N] [--seed S]`:
  laser localization without beacons (`ThinkingCap.Navigation.MCL`) on a
  map the robot is given. In each `map_server` map (default: nav2's
  `turtlebot3_world` and `warehouse`), each run starts the office robot
  (`priv/examples/office_robot.rdf` without its beacon sensor; its
  odometry error model on) at a random reachable pose, tells the
  localizer that pose off by up to 0.5 m and 0.3 rad (drawn with the
  seed), and patrols random reachable waypoints with the planner for
  5 simulated minutes; at a random time between 2 and 3 minutes the robot
  is carried at least 3 m away to free space without notice.

  Figures, over every 0.1 s of all runs except the 10 s after the start
  and after the kidnapping: `rms_m` and `max_m` of the position error;
  `lost`, the runs whose error is above 1 m at the end.

  Ends with `localize: runs=N rms_m=E max_m=M lost=L`.
  """

  alias ThinkingCap.Bench.NavRun
  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Tuples
  require Tuples

  @duration 300.0
  @settle 10.0

  def run(args) do
    opts = NavRun.options(args, 5)
    tmp = NavRun.tmp_dir()
    rdf = write_rdf(tmp)
    {:ok, d} = Description.load(rdf)
    radius = d.footprint.radius

    results =
      Enum.flat_map(opts.maps, fn yaml ->
        name = Path.basename(yaml, ".yaml")
        wdf = write_wdf(tmp, name, yaml)
        {grid, _tight} = NavRun.grids(wdf, radius)
        {:ok, world} = Sim.World.load(wdf)
        free? = fn cell -> Sim.World.free?(world, Grid.centre(grid, cell), radius + 0.05) end
        rng = :rand.seed_s(:exsss, {opts.seed, 44, 1})

        {runs, _} =
          Enum.map_reduce(1..opts.runs, rng, fn i, rng ->
            {plan, rng} = draw(grid, free?, rng)
            r = one_run(wdf, rdf, plan, opts.seed * 1000 + i)
            IO.puts(line(name, i, r))
            {r, rng}
          end)

        print(name, runs)
        runs
      end)

    print("localize", results)
    File.rm_rf!(tmp)
  end

  # the office robot without its beacon sensor
  defp write_rdf(dir) do
    {:ok, data, _positions} =
      ThinkingCap.Config.Literal.parse(File.read!(NavRun.rdf()), NavRun.rdf())

    sensors = Enum.reject(data[:sensors], &(&1[:type] == :beacon_laser))
    path = Path.join(dir, "no_beacons.rdf")
    File.write!(path, inspect(Keyword.put(data, :sensors, sensors), limit: :infinity))
    path
  end

  defp write_wdf(dir, name, yaml) do
    path = Path.join(dir, "#{name}.wdf")
    File.write!(path, inspect(name: name, map: [yaml: yaml]))
    path
  end

  # the start, the initial estimate off by up to 0.5 m and 0.3 rad, eight
  # waypoints to patrol, the kidnapping's time and place
  defp draw(grid, free?, rng) do
    {cells, rng} = Enum.map_reduce(1..10, rng, fn _, rng -> free_reachable(grid, free?, rng) end)

    [start, kidnap | waypoints] = Enum.map(cells, &Grid.centre(grid, &1))
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    {w, rng} = :rand.uniform_s(rng)
    {th, rng} = :rand.uniform_s(rng)
    {at, rng} = :rand.uniform_s(rng)
    {sx, sy} = start
    offset = 0.5 * u
    dir = 2 * :math.pi() * v
    heading = (th - 0.5) * 2 * :math.pi()

    plan = %{
      start: {sx, sy, heading},
      initial:
        {sx + offset * :math.cos(dir), sy + offset * :math.sin(dir), heading + (w - 0.5) * 0.6},
      waypoints: waypoints,
      kidnap_at: 120.0 + 60.0 * at,
      kidnap_to: kidnap
    }

    if dist(start, kidnap) >= 3.0, do: {plan, rng}, else: draw(grid, free?, rng)
  end

  defp free_reachable(grid, free?, rng) do
    {cell, rng} = NavRun.free_cell(grid, rng)
    if free?.(cell), do: {cell, rng}, else: free_reachable(grid, free?, rng)
  end

  defp one_run(wdf, rdf, plan, seed) do
    {:ok, sim} = Sim.start_link(world: wdf, mode: :fast, running: false, step: 0.05, seed: seed)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.MCL,
         [initial: plan.initial, initial_sigma: {0.5, 0.3}, seed: seed] ++
           NavRun.env_params("TC_MCL")},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner: {ThinkingCap.Planner.Monitor, [task: {:patrol, plan.waypoints}], period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :loc,
        rdf: rdf,
        at: plan.start,
        controller: {Sim.LockstepController, modules: modules, rdf: rdf, wdf: wdf}
      )

    {errors, _} =
      Enum.map_reduce(1..round(@duration * 10), false, fn step, kidnapped ->
        :ok = Sim.run_for(sim, 0.1)
        t = step / 10

        kidnapped =
          if not kidnapped and t >= plan.kidnap_at do
            {kx, ky} = plan.kidnap_to
            {:ok, {_, _, th}} = Sim.pose(sim, :loc)
            :ok = Sim.teleport(sim, :loc, {kx, ky, th})
            true
          else
            kidnapped
          end

        {:ok, {x, y, _}} = Sim.pose(sim, :loc)
        {:ok, c} = Sim.controller_state(sim, :loc)
        Tuples.pose(_, %{pose: {ex, ey, _}} = p) = Lockstep.latest(c.lock, Tuples.pose(:loc))

        error = :math.sqrt((ex - x) ** 2 + (ey - y) ** 2)
        near_kidnap = t >= plan.kidnap_at - 1 and t <= plan.kidnap_at + 30

        # --trace: round the kidnapping, and wherever the estimate is off
        if Process.get(:trace) and (near_kidnap or error > 0.3) and rem(step, 5) == 0 do
          IO.puts(
            "    t=#{NavRun.fmt(t)} true (#{NavRun.fmt(x)}, #{NavRun.fmt(y)}) estimate " <>
              "(#{NavRun.fmt(ex)}, #{NavRun.fmt(ey)}) #{p.status} #{p.confidence}"
          )
        end

        {{t, error}, kidnapped}
      end)

    blocked = Sim.status(sim).blocked
    GenServer.stop(sim)

    counted =
      for {t, e} <- errors,
          t > @settle and not (t >= plan.kidnap_at and t < plan.kidnap_at + @settle),
          do: {t, e}

    {_, final} = List.last(errors)
    {worst_at, _} = Enum.max_by(counted, &elem(&1, 1), fn -> {0.0, 0.0} end)

    %{
      errors: Enum.map(counted, &elem(&1, 1)),
      worst_at: worst_at,
      final: final,
      blocked: blocked,
      kidnap_at: plan.kidnap_at
    }
  end

  defp line(name, i, r) do
    "  #{name} #{i}: rms #{NavRun.fmt(rms(r.errors))} m, max #{NavRun.fmt(Enum.max(r.errors))} m, " <>
      "worst at #{NavRun.fmt(r.worst_at)} s, final #{NavRun.fmt(r.final)} m, kidnapped at #{NavRun.fmt(r.kidnap_at)} s, blocked #{r.blocked}"
  end

  defp print(label, runs) do
    errors = Enum.flat_map(runs, & &1.errors)
    lost = Enum.count(runs, &(&1.final > 1.0))

    IO.puts(
      "#{label}: runs=#{length(runs)} rms_m=#{:erlang.float_to_binary(rms(errors), decimals: 3)} " <>
        "max_m=#{:erlang.float_to_binary(Enum.max(errors, fn -> 0.0 end) * 1.0, decimals: 3)} lost=#{lost}"
    )
  end

  defp rms([]), do: 0.0
  defp rms(xs), do: :math.sqrt(Enum.sum(Enum.map(xs, &(&1 * &1))) / length(xs))

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
end
