defmodule ThinkingCap.Bench.Sim do
  @moduledoc """
  `mix tc.bench sim [--seconds S] [--robots N] [--scale-seconds T] [--walkers W]
  [--nodes K] [--nodes-seconds U] [--only nodes]`: the simulator on the
  workload of Stage's `cave.world` benchmark, then at fleet scale, then
  across nodes.

  N robots (default 100), each with a ring of 16 sonars (15° cone, 5 m,
  three rays per cone, up to two specular bounces, crosstalk on) and a
  180-beam laser (180°, 8 m), wandering safely (`ThinkingCap.Sim.Wander`,
  in-process), with a 100 ms sensor and control step, in nav2's warehouse
  map (`bench/warehouse.wdf`, 30 m × 50 m at 3 cm), as fast as possible
  for S simulated seconds (default 600); then the same with 1 and 10
  robots.

  Fleet scale (`sim_scale` line): 10 × N robots in the warehouse map tiled
  5 × 2 (150 m × 100 m: the same robot density), among W walkers (default
  2 × N: 200 people among 1,000 robots; `ThinkingCap.Sim.Crowd`, seeded,
  routes of three points up to 10 m apart), for T simulated seconds
  (default 60). `ray_ratio` is its rays per wall second over those of the
  N-robot run (no walkers): 1.0 when the cost per ray does not depend on
  the fleet.

  Across nodes (`sim_nodes` line): 20 × N robots and 4 × N walkers in
  the map tiled 5 × 4 (150 m × 200 m, the same density), spread over K
  local nodes (default 2, started with OTP's `:peer`; `ThinkingCap.Sim`'s
  `:nodes`; this VM, made a node, coordinates), for U simulated seconds
  (default 20), then the same on the first of them alone (`rtf_1`):
  `equal` is 1 when every robot's pose at U / 2 and U is the same in
  both runs. `cpu_ms_step` is the CPU time of a step on every node (the
  coordinator and the regions), `cpu_ms_step_1` that of the node alone:
  what the split costs, whatever share of the cores the runs get on a
  shared machine. The peers' schedulers run at normal priority, the reference
  too: this VM's may run at real-time priority, and would take the CPU
  from them on a shared machine.
  `--only nodes` runs this part alone.

  `cpu_us_rstep`: this VM's CPU time (user and system, from `/proc`)
  over robots × steps, in µs: the cost of a robot-step whatever share of
  the cores the run got.

  Real-time factor: simulated seconds per wall second. Rays: the rays of
  every sample (sonar cone rays and laser beams, without counting bounces)
  per wall second. Stage 4.3 ran the 100-robot workload at about 14× real
  time with one ray per sample and no reflections.
  """

  alias ThinkingCap.Sim
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Config.RosMap

  @dir Path.expand(".", __DIR__)

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args,
        strict: [
          seconds: :float,
          robots: :integer,
          scale_seconds: :float,
          walkers: :integer,
          nodes: :integer,
          nodes_seconds: :float,
          only: :string
        ]
      )

    n = opts[:robots] || 100
    {:ok, description} = Description.load(Path.join(@dir, "cave_robot.rdf"))
    {:ok, world} = Sim.World.load(Path.join(@dir, "warehouse.wdf"))

    if opts[:only] != "nodes", do: one_node(opts, n, description, world)
    across_nodes(opts, n, description, world)
  end

  defp one_node(opts, n, description, world) do
    seconds = opts[:seconds] || 600.0

    IO.puts(
      "sim: #{world.name} map, #{seconds} simulated s, step 0.1 s, " <>
        "#{System.schedulers_online()} schedulers"
    )

    results =
      for robots <- Enum.uniq([n, 1, 10]), into: %{} do
        r = measure(world, description, robots, seconds)

        IO.puts(
          "  #{String.pad_leading(Integer.to_string(robots), 3)} robots: " <>
            "#{fmt(r.wall)} s wall, rtf #{fmt(r.rtf)}, #{fmt(r.rays_per_s / 1.0e6)} M rays/s, " <>
            "#{fmt(r.cpu_us)} µs CPU a robot-step, #{r.bumps} blocked robot-steps"
        )

        {robots, r}
      end

    main = results[n]

    IO.puts(
      "sim: robots=#{n} rtf=#{fmt(main.rtf)} rays_per_s=#{round(main.rays_per_s)} " <>
        "rtf_1=#{fmt(results[1].rtf)} rtf_10=#{fmt(results[10].rtf)} cpu_us_rstep=#{fmt(main.cpu_us)}"
    )

    scale_seconds = opts[:scale_seconds] || 60.0

    {:ok, big} =
      Sim.World.from_wdf(%{world.wdf | name: "warehouse 5x2", grid: tile(world.wdf.grid, 5, 2)})

    n_walkers = opts[:walkers] || 2 * n
    walkers = Sim.Crowd.walkers(big, count: n_walkers, seed: 42)
    r = measure(big, description, 10 * n, scale_seconds, walkers)

    IO.puts(
      "  #{10 * n} robots and #{n_walkers} walkers, warehouse tiled 5 x 2, " <>
        "#{scale_seconds} simulated s: " <>
        "#{fmt(r.wall)} s wall, rtf #{fmt(r.rtf)}, #{fmt(r.rays_per_s / 1.0e6)} M rays/s, " <>
        "#{fmt(r.cpu_us)} µs CPU a robot-step, #{r.bumps} blocked robot-steps"
    )

    IO.puts(
      "sim_scale: robots=#{10 * n} walkers=#{n_walkers} rtf=#{fmt(r.rtf)} " <>
        "ray_ratio=#{fmt(r.rays_per_s / main.rays_per_s)} rays_per_s=#{round(r.rays_per_s)} " <>
        "cpu_us_rstep=#{fmt(r.cpu_us)}"
    )
  end

  # 20 x N robots and 4 x N walkers in the warehouse tiled 5 x 4, on
  # nodes (this VM and peers), then on this node alone
  defp across_nodes(opts, n, description, world) do
    k = opts[:nodes] || 2
    seconds = opts[:nodes_seconds] || 20.0
    robots = 20 * n
    start_distribution()

    peers = ThinkingCap.Testing.Cluster.start(k, connection: :dist, apps: [])
    nodes = Enum.map(peers, & &1.node)

    wdf = %{world.wdf | name: "warehouse 5x4", grid: tile(world.wdf.grid, 5, 4)}
    {:ok, big} = Sim.World.from_wdf(wdf)
    walkers = Sim.Crowd.walkers(big, count: 4 * n, seed: 42)

    opts = [
      world: wdf,
      description: description,
      robots: robots,
      seconds: seconds,
      sample_every: seconds / 2,
      seed: 42,
      walkers: walkers
    ]

    IO.puts(
      "sim_nodes: #{robots} robots and #{4 * n} walkers, warehouse tiled 5 x 4, " <>
        "#{seconds} simulated s, nodes #{inspect(nodes)}"
    )

    # the coordinator here, the regions on the peers
    spread = ThinkingCap.Testing.FleetRun.run(opts ++ [sim: [nodes: nodes], cpu_nodes: nodes])
    s = spread.status
    # CPU a step, every node's: the coordinator's and the regions'
    peers_ms = spread.node_cpu |> Map.values() |> Enum.sum() |> Kernel.*(1000 / s.steps)
    cpu_step = spread.cpu * 1000 / s.steps + peers_ms
    per_node = spread.placements |> List.last() |> Map.values() |> Enum.frequencies()

    IO.puts(
      "  #{k} nodes: #{fmt(spread.wall)} s wall, rtf #{fmt(seconds / spread.wall)}, " <>
        "#{fmt(s.rays / spread.wall / 1.0e6)} M rays/s, robots per node " <>
        "#{Enum.map_join(nodes, "/", &Map.get(per_node, &1, 0))}, " <>
        "#{s.node_handovers} handed over between nodes, #{s.ghosts} ghosts at the last step, " <>
        "coordinator CPU #{fmt(spread.cpu * 1000 / s.steps)} ms a step, the regions' " <>
        "#{fmt(peers_ms)} ms (#{Enum.map_join(nodes, "/", &fmt(spread.node_cpu[&1] * 1000 / s.steps))})"
    )

    # the reference on the first peer alone: the same priority as the
    # regions' (this VM's schedulers may run at real-time priority)
    alone =
      ThinkingCap.Testing.Cluster.call(
        hd(peers),
        ThinkingCap.Testing.FleetRun,
        :run,
        [opts],
        :infinity
      )

    ThinkingCap.Testing.Cluster.stop(peers)

    cpu_step_1 = alone.cpu * 1000 / alone.status.steps

    IO.puts(
      "  1 node: #{fmt(alone.wall)} s wall, rtf #{fmt(seconds / alone.wall)}, " <>
        "#{fmt(alone.status.rays / alone.wall / 1.0e6)} M rays/s, CPU #{fmt(cpu_step_1)} ms a step"
    )

    equal = if spread.samples == alone.samples, do: 1, else: 0

    IO.puts(
      "sim_nodes: nodes=#{k} robots=#{robots} rtf=#{fmt(seconds / spread.wall)} " <>
        "equal=#{equal} rtf_1=#{fmt(seconds / alone.wall)} walkers=#{4 * n} " <>
        "cpu_ms_step=#{fmt(cpu_step)} cpu_ms_step_1=#{fmt(cpu_step_1)}"
    )
  end

  defp start_distribution do
    {_, 0} = System.cmd("epmd", ["-daemon"])

    unless Node.alive?() do
      {:ok, _} = :net_kernel.start([:"tc_sim_bench_#{System.pid()}@127.0.0.1", :longnames])
      Node.set_cookie(:"sim_bench_#{:rand.uniform(1_000_000_000)}")
    end
  end

  # the occupancy grid repeated nx times across and ny times up
  defp tile(grid, nx, ny) do
    w = grid.width

    rows =
      for row <- 0..(grid.height - 1) do
        line = binary_part(grid.data, row * w, w)
        :binary.copy(line, nx)
      end

    band = IO.iodata_to_binary(rows)
    %{grid | width: w * nx, height: grid.height * ny, data: :binary.copy(band, ny)}
  end

  defp measure(world, description, robots, seconds, walkers \\ []) do
    {:ok, sim} =
      Sim.start_link(
        world: world,
        mode: :fast,
        running: false,
        step: 0.1,
        seed: 42,
        walkers: walkers
      )

    rng = :rand.seed_s(:exsss, {42, robots, 1})
    place(sim, world, description, robots, rng)
    ticks = ThinkingCap.Bench.ProcStat.clock_ticks()
    t0 = System.monotonic_time()
    cpu0 = cpu_ms(ticks)
    :ok = Sim.run_for(sim, seconds)
    wall = System.convert_time_unit(System.monotonic_time() - t0, :native, :microsecond) / 1.0e6
    cpu = cpu_ms(ticks) - cpu0
    status = Sim.status(sim)
    GenServer.stop(sim)

    %{
      wall: wall,
      # CPU time of this OS process a robot-step, µs: less sensitive than
      # the wall clock to what other programs take from the cores
      cpu_us: cpu * 1000 / max(1, robots * status.steps),
      rtf: status.time / wall,
      rays_per_s: status.rays / wall,
      bumps: status.blocked
    }
  end

  # this OS process's CPU time (user and system), ms
  defp cpu_ms(ticks) do
    [_, rest] = File.read!("/proc/self/stat") |> String.split(")", parts: 2)
    fields = String.split(rest)

    (String.to_integer(Enum.at(fields, 11)) + String.to_integer(Enum.at(fields, 12))) * 1000 /
      ticks
  end

  # random free places inside the building (known-free cells)
  defp place(_sim, _world, _d, 0, _rng), do: :ok

  defp place(sim, world, d, n, rng) do
    grid = world.wdf.grid
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    {w, rng} = :rand.uniform_s(rng)
    {col, row} = {floor(u * grid.width), floor(v * grid.height)}
    {ox, oy, _} = grid.origin
    x = ox + (col + 0.5) * grid.resolution
    y = oy + (row + 0.5) * grid.resolution

    with 0 <- RosMap.cell(grid, col, row),
         true <- Sim.World.free?(world, {x, y}, d.footprint.radius + 0.3),
         :ok <-
           Sim.add_robot(sim, :"r#{n}",
             description: d,
             at: {x, y, (w - 0.5) * 2 * :math.pi()},
             controller: {Sim.Wander, [seed: n]}
           ) do
      place(sim, world, d, n - 1, rng)
    else
      _ -> place(sim, world, d, n, rng)
    end
  end

  defp fmt(x) when x >= 100, do: :erlang.float_to_binary(x * 1.0, decimals: 0)
  defp fmt(x) when x >= 10, do: :erlang.float_to_binary(x * 1.0, decimals: 1)
  defp fmt(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)
end
