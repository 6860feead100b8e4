defmodule ThinkingCap.Testing.FleetRun do
  @moduledoc """
  A fleet of wandering robots run as fast as possible, with the poses
  sampled along the way: the same run on one node and across nodes can
  be compared pose for pose. A function of this app (not of a test file)
  so that it runs on a peer node too (`ThinkingCap.Testing.Cluster.call/5`).

      ThinkingCap.Testing.FleetRun.run(world: wdf, description: d, robots: 40,
                                        seconds: 20.0, sample_every: 1.0, sim: [nodes: nodes])
  """

  alias ThinkingCap.Sim

  @doc """
  Starts a simulation in `:fast` mode (`:sim` options added to `world:`,
  `seed:`, `step:` and `walkers:`), puts `robots` robots of `description`
  wandering (`ThinkingCap.Sim.Wander`) at free places drawn from `seed`,
  runs `seconds` of simulated time, samples every robot's true pose
  every `sample_every` simulated seconds, and stops. Returns
  `%{samples: [%{id => pose}], wall: seconds, cpu: seconds, status:
  Sim.status/1, placements: [%{id => node}], node_cpu: %{node => seconds}}`
  (the placement after each sample; `wall` the time spent stepping,
  samples not counted, `cpu` this node's CPU time meanwhile, every
  scheduler's, and `node_cpu` that of each node of `:cpu_nodes`).
  Options: `:world` (a WDF path or `ThinkingCap.Config.WDF`),
  `:description`, `:robots`, `:seconds`, `:sample_every` (default: only
  at the end), `:step` (default 0.1), `:seed` (default 1), `:walkers`
  (default `[]`), `:clearance` around a start place (default 0.3), `:sim`,
  `:cpu_nodes` (default `[]`).
  """
  @spec run(keyword()) :: %{
          samples: [%{atom() => tuple()}],
          wall: float(),
          cpu: float(),
          status: map(),
          placements: [%{atom() => node()}],
          node_cpu: %{node() => float()}
        }
  def run(opts) do
    d = Keyword.fetch!(opts, :description)
    seconds = Keyword.fetch!(opts, :seconds)
    every = Keyword.get(opts, :sample_every, seconds)
    seed = Keyword.get(opts, :seed, 1)

    sim_opts =
      [
        world: Keyword.fetch!(opts, :world),
        mode: :fast,
        running: false,
        step: Keyword.get(opts, :step, 0.1),
        seed: seed,
        walkers: Keyword.get(opts, :walkers, [])
      ] ++ Keyword.get(opts, :sim, [])

    {:ok, sim} = Sim.start_link(sim_opts)

    try do
      world = Sim.world(sim)
      rng = :rand.seed_s(:exsss, {seed, 77, 5})
      :ok = place(sim, world, d, Keyword.fetch!(opts, :robots), opts, rng)

      cpu_nodes = Keyword.get(opts, :cpu_nodes, [])
      zero = Map.new(cpu_nodes, &{&1, 0})

      {samples, placements, wall, cpu, node_cpu} =
        Enum.reduce(1..max(round(seconds / every), 1), {[], [], 0, 0, zero}, fn _, acc ->
          stretch(sim, every, cpu_nodes, acc)
        end)

      %{
        samples: Enum.reverse(samples),
        placements: Enum.reverse(placements),
        wall: System.convert_time_unit(wall, :native, :microsecond) / 1.0e6,
        cpu: cpu / 1000,
        status: Sim.status(sim),
        node_cpu: Map.new(node_cpu, fn {n, ms} -> {n, ms / 1000} end)
      }
    after
      GenServer.stop(sim, :normal, 60_000)
    end
  end

  # `every` simulated seconds, then a sample
  defp stretch(sim, every, cpu_nodes, {samples, placements, wall, cpu, node_cpu}) do
    n0 = runtimes(cpu_nodes)
    t0 = System.monotonic_time()
    {c0, _} = :erlang.statistics(:runtime)
    :ok = Sim.run_for(sim, every)
    {c1, _} = :erlang.statistics(:runtime)
    wall = wall + System.monotonic_time() - t0
    node_cpu = Map.merge(node_cpu, runtimes(cpu_nodes), fn n, acc, c -> acc + c - n0[n] end)

    {[Sim.robots(sim) | samples], [Sim.placement(sim) | placements], wall, cpu + c1 - c0,
     node_cpu}
  end

  # each node's CPU time so far (ms), every scheduler's
  defp runtimes(nodes),
    do: Map.new(nodes, &{&1, elem(:erpc.call(&1, :erlang, :statistics, [:runtime]), 0)})

  defp place(_sim, _world, _d, 0, _opts, _rng), do: :ok

  defp place(sim, world, d, n, opts, rng) do
    {{x, y, theta}, rng} = Sim.World.random_pose(world, rng)
    clearance = Keyword.get(opts, :clearance, 0.3)

    with true <- Sim.World.known_free?(world, {x, y}),
         true <- Sim.World.free?(world, {x, y}, d.footprint.radius + clearance),
         :ok <-
           Sim.add_robot(sim, :"r#{n}",
             description: d,
             at: {x, y, theta},
             controller: {Sim.Wander, [seed: n]}
           ) do
      place(sim, world, d, n - 1, opts, rng)
    else
      _ -> place(sim, world, d, n, opts, rng)
    end
  end
end
