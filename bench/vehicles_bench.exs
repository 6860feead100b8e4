defmodule ThinkingCap.Bench.Vehicles do
  @moduledoc """
  `mix tc.bench vehicles [--runs N] [--seed S] [--trace]`: car-like AGVs
  docking in the warehouse example (`priv/examples/warehouse.wdf`).

  The forklift (`priv/examples/forklift.rdf`, tricycle, backs into pallet
  stations forks first) and the tug (`priv/examples/tug.rdf`, Ackermann,
  drives into hitch and charging stations) each run N times (default 10)
  from a random start (free for the robot's disc, reachable, heading at
  random) to a random one of their docking stations at least 3 m away,
  with the whole stack in lockstep with the simulator: perception, EKF
  localization on beacons, `ThinkingCap.Control.VehicleDrive` and the
  planner/monitor (`{:go_to, station}`).

  A run succeeds when the monitor reports the task done within 240
  simulated seconds and the simulator's true pose is within the RDF's
  docking tolerances (position and heading). Collisions: runs in which the
  robot touched anything (a blocked step in the simulator). Ends with
  `vehicles: runs=R success=K collisions=C` (R = 2N).
  """

  alias ThinkingCap.Navigation.{AStar, Grid, Maps}
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.LockstepController
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Tuples
  require Tuples
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @root Path.expand("..", __DIR__)
  @limit 240.0

  @vehicles [
    forklift: [rdf: "priv/examples/forklift.rdf", stations: "p_"],
    tug: [rdf: "priv/examples/tug.rdf", stations: "t_"]
  ]

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args, strict: [runs: :integer, seed: :integer, trace: :boolean])

    runs = opts[:runs] || 10
    seed = opts[:seed] || 1
    Process.put(:trace, opts[:trace] || false)
    wdf_path = Path.join(@root, "priv/examples/warehouse.wdf")
    wdf = ThinkingCap.Config.read!(wdf_path)

    results =
      Enum.flat_map(@vehicles, fn {name, v} ->
        rdf = Path.join(@root, v[:rdf])
        {:ok, d} = Description.load(rdf)

        stations =
          for w <- wdf.waypoints, String.starts_with?(to_string(w.name), v[:stations]), do: w

        rng = :rand.seed_s(:exsss, {seed, :erlang.phash2(name), 5})
        cases = cases(wdf, d, stations, runs, rng)

        r =
          cases
          |> Enum.with_index(1)
          |> Enum.map(fn {{start, station}, i} ->
            r = one_run(wdf_path, rdf, d, start, station, seed * 1000 + i)
            line(name, i, start, station, r)
            r
          end)

        summary(to_string(name), r)
        r
      end)

    summary("vehicles", results)
  end

  defp line(name, i, {x, y, th}, station, r) do
    IO.puts(
      "  #{name} #{i}: #{if r.success, do: "ok  ", else: "FAIL"} #{fmt(r.time)} s " <>
        "from (#{fmt(x)}, #{fmt(y)}, #{fmt(th)}) to #{station.name}: " <>
        "off by #{fmt(r.error)} m, #{fmt(r.heading_error)} rad, blocked #{r.blocked}" <>
        if(r.success, do: "", else: " (plan #{r.state}, vehicle #{r.vehicle})")
    )
  end

  defp summary(label, results) do
    ok = Enum.count(results, & &1.success)
    collisions = Enum.count(results, &(&1.blocked > 0))
    time = mean(for r <- results, r.success, do: r.time)

    IO.puts(
      "#{label}: runs=#{length(results)} success=#{ok} collisions=#{collisions} " <>
        "mean_time_s=#{fmt(time)}"
    )
  end

  defp mean([]), do: 0.0
  defp mean(xs), do: Enum.sum(xs) / length(xs)

  # random starts, free and reachable on the planner's grid, each with a
  # station at least 3 m away
  defp cases(wdf, d, stations, runs, rng) do
    {:ok, world} = Sim.World.from_wdf(wdf)
    radius = d.footprint.radius
    grid = wdf |> Maps.grid_from_wdf(resolution: 0.1) |> Maps.inflate(radius + 0.15)

    {cases, _} =
      Enum.map_reduce(1..runs, rng, fn _, rng -> one_case(grid, world, radius, stations, rng) end)

    cases
  end

  defp one_case(grid, world, radius, stations, rng) do
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    {w, rng} = :rand.uniform_s(rng)
    {k, rng} = :rand.uniform_s(length(stations), rng)
    station = Enum.at(stations, k - 1)
    cell = {floor(u * grid.width), floor(v * grid.height)}
    {x, y} = Grid.centre(grid, cell)
    {gx, gy, _} = station.at

    with true <- Grid.passable?(grid, cell),
         true <- Sim.World.free?(world, {x, y}, radius + 0.1),
         true <- :math.sqrt((gx - x) ** 2 + (gy - y) ** 2) >= 3.0,
         {:ok, _} <- AStar.plan_world(grid, {x, y}, {gx, gy}) do
      {{{x, y, normalize_angle((w - 0.5) * 2 * :math.pi())}, station}, rng}
    else
      _ -> one_case(grid, world, radius, stations, rng)
    end
  end

  defp one_run(wdf, rdf, d, start, station, seed) do
    {:ok, sim} = Sim.start_link(world: wdf, mode: :fast, running: false, step: 0.05, seed: seed)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.Localizer, [initial: start, initial_sigma: {0.1, 0.05}]},
      control: {ThinkingCap.Control.VehicleDrive, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor, [task: {:go_to, station.name}, stuck_after: 40.0],
         period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :agv,
        rdf: rdf,
        at: start,
        controller: {LockstepController, modules: modules, rdf: rdf, wdf: wdf}
      )

    {plan, vehicle} = drive(sim)
    {:ok, {x, y, th}} = Sim.pose(sim, :agv)
    status = Sim.status(sim)
    GenServer.stop(sim)

    {gx, gy, gth} = station.at
    error = :math.sqrt((gx - x) ** 2 + (gy - y) ** 2)
    heading_error = abs(normalize_angle(th - gth))
    dock = d.docking
    state = if plan, do: elem(plan, 2).state, else: nil

    %{
      success:
        state == :done and error <= dock.position_tolerance and
          heading_error <= dock.heading_tolerance,
      state: state,
      vehicle: if(vehicle, do: elem(vehicle, 2).state, else: nil),
      time: status.time,
      error: error,
      heading_error: heading_error,
      blocked: status.blocked
    }
  end

  # half a second at a time until the plan is done or failed, or time is up
  defp drive(sim) do
    :ok = Sim.run_for(sim, 0.5)
    {:ok, cstate} = Sim.controller_state(sim, :agv)
    plan = Lockstep.latest(cstate.lock, Tuples.plan(:agv))
    vehicle = Lockstep.latest(cstate.lock, Tuples.vehicle(:agv))
    time = Sim.time(sim)

    if Process.get(:trace) do
      {:ok, {x, y, th}} = Sim.pose(sim, :agv)

      IO.puts(
        "    t=#{fmt(time)} (#{fmt(x)}, #{fmt(y)}, #{fmt(th)}) #{inspect(vehicle && elem(vehicle, 2).state)}"
      )
    end

    case plan do
      Tuples.plan(_, %{state: s}) when s in [:done, :failed] ->
        # let the robot come to rest on the dock
        :ok = Sim.run_for(sim, 1.0)
        {plan, vehicle}

      _ when time >= @limit ->
        {plan, vehicle}

      _ ->
        drive(sim)
    end
  end

  defp fmt(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)
end
