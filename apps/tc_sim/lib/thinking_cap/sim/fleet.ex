defmodule ThinkingCap.Sim.Fleet do
  @moduledoc """
  A fleet of simulated robots as an ADF module: it puts `count` robots
  that wander on their own (`ThinkingCap.Sim.Wander`, in-process) into
  the simulation of the ADF's world, beside the ADF's own robot, and
  shows them on the dashboard.

      fleet: [module: ThinkingCap.Sim.Fleet, activity: :periodic, period: 0.2,
              deadline: 0.1, params: [count: 99, rdf: "fleet_robot.rdf", seed: 3]]

  The robots (ids `:fleet_1`, `:fleet_2`, ...) start at free places of
  the world drawn from `seed` (known-free cells of its map, if it has
  one). Only their true poses go to the blackboard (`:sim_pose`, ten
  times a simulated second), so the dashboard draws a hundred robots
  without a hundred laser scans. At each release the module writes where
  the world's walkers stand (its WDF's `crowd:` section):
  `{:sim_walkers, world_name, %{walkers: [{x, y, radius}], stamp: t}}`.
  When the module stops, its robots leave the simulation.

  The simulation is the one `ThinkingCap.Sim.Robot` joins
  (`ThinkingCap.Sim.Worlds`): the first of the two to start starts it,
  with the same `seed`, `step` and `speed` params.
  """
  use ThinkingCap.Module

  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim
  alias ThinkingCap.Tuples
  require Tuples

  # places drawn before giving up on a crowded world
  @attempts 100

  @impl true
  def params do
    [
      count: {{:int_range, 0, 5000}, default: 99, doc: "robots in the fleet"},
      rdf: {:string, required: true, doc: "their RDF, relative to the ADF's rdf: directory"},
      seed: {:integer, default: 1, doc: "their places and wandering are drawn from it"},
      clearance: {:number, default: 0.3, doc: "free space kept around a start place, m"},
      world: {:string, doc: "the simulated world's WDF, as ThinkingCap.Sim.Robot's world:"},
      step: {:pos_number, default: 0.01, doc: "the world's step, s, if this module starts it"},
      speed: {:pos_number, default: 1.0, doc: "simulated s per wall s, if this module starts it"}
    ]
  end

  @impl true
  def replay, do: [trace: false]

  @impl true
  def init(params, context) do
    # the declared params with their defaults
    params = Map.merge(Map.new(context.params || %{}), Map.new(params))

    with {:ok, wdf} <- wdf(params, context),
         {:ok, description} <- Description.load(rdf(params, context)),
         {:ok, sim} <-
           Sim.Worlds.ensure(wdf, seed: params.seed, step: params.step, speed: params.speed),
         {:ok, ids} <- place(sim, description, params) do
      {:ok, %{sim: sim, ids: ids, world: Sim.world(sim).name}}
    else
      {:error, message} -> raise ArgumentError, "#{inspect(context.name)}: #{message}"
    end
  end

  @impl true
  def handle_cycle(_release, state) do
    walkers = Sim.walker_discs(state.sim)
    stamp = Sim.time(state.sim)
    payload = %{walkers: walkers, stamp: stamp}
    {[out: Tuples.keyed(Tuples.sim_walkers(state.world, payload))], state}
  end

  @impl true
  def terminate(_reason, state) do
    if Process.alive?(state.sim), do: Enum.each(state.ids, &Sim.remove_robot(state.sim, &1))
    :ok
  end

  defp wdf(params, context) do
    case {params[:world], context.wdf} do
      {nil, nil} -> {:error, "needs the ADF's wdf: or a world: param"}
      {nil, wdf} -> {:ok, wdf}
      {world, nil} -> {:ok, Path.expand(world)}
      {world, wdf} -> {:ok, Path.expand(world, Path.dirname(wdf))}
    end
  end

  defp rdf(params, context) do
    if context.rdf, do: Path.expand(params.rdf, Path.dirname(context.rdf)), else: params.rdf
  end

  # count robots at free places drawn from the seed, ids :fleet_1, ...
  defp place(sim, description, params) do
    world = Sim.world(sim)
    rng = :rand.seed_s(:exsss, {params.seed, 31, 7})
    r = description.footprint.radius + params.clearance

    Enum.reduce_while(1..params.count//1, {:ok, [], rng}, fn k, {:ok, ids, rng} ->
      id = :"fleet_#{k}"

      case add(sim, world, description, id, r, params.seed + k, rng, @attempts) do
        {:ok, rng} -> {:cont, {:ok, [id | ids], rng}}
        {:error, message} -> {:halt, {:error, message}}
      end
    end)
    |> case do
      {:ok, ids, _rng} -> {:ok, Enum.reverse(ids)}
      {:error, message} -> {:error, message}
    end
  end

  defp add(_sim, world, _d, id, _r, _seed, _rng, 0),
    do: {:error, "no free place for #{inspect(id)} in #{world.name} after #{@attempts} draws"}

  defp add(sim, world, d, id, r, seed, rng, left) do
    {{x, y, theta}, rng} = Sim.World.random_pose(world, rng)

    with true <- Sim.World.known_free?(world, {x, y}) and Sim.World.free?(world, {x, y}, r),
         :ok <-
           Sim.add_robot(sim, id,
             description: d,
             at: {x, y, theta},
             controller: {Sim.Wander, [seed: seed]},
             publish: [:sim_pose]
           ) do
      {:ok, rng}
    else
      _ -> add(sim, world, d, id, r, seed, rng, left - 1)
    end
  end
end
