defmodule ThinkingCap.Sim.Robot do
  @moduledoc """
  The simulated robot: the `ThinkingCap.Robot` driver that puts the ADF's
  robot into the simulation of the ADF's world. Writing
  `module: ThinkingCap.Sim.Robot` for the robot's base in an ADF is the
  whole difference from a real robot's driver.

  The world's simulation (`ThinkingCap.Sim`, real-time mode) is started on
  first use and shared by every simulated robot of that WDF on the node
  (`ThinkingCap.Sim.Worlds`). ADF params:

    * `world:` - the WDF of the simulated world, when it is not the one
      the robot's modules are told (a robot exploring a building it knows
      nothing of: the ADF's `wdf:` is empty, the simulator's is the
      building); a relative path is taken from the ADF's `wdf:` directory;
    * `at:` - the start pose `{x, y, theta}`, a point, or a waypoint of the
      WDF (default: the WDF's first waypoint, else the origin);
    * `seed:` - the world's seed when this robot starts it (default 1);
    * `step:` - the world's step in seconds when this robot starts it
      (default 0.01);
    * `speed:` - the world's simulated seconds per wall second when this
      robot starts it (default 1.0; see `ThinkingCap.Sim.start_link/1`);
    * `command_timeout:` - see `ThinkingCap.Robot`.

  If the driver restarts, it takes its robot over where it stands.
  """
  use ThinkingCap.Robot

  alias ThinkingCap.Sim

  @impl true
  def open(description, context) do
    params = context.params

    with {:ok, wdf} <- wdf(context),
         {:ok, sim} <-
           Sim.Worlds.ensure(wdf,
             seed: Keyword.get(params, :seed, 1),
             step: Keyword.get(params, :step, 0.01),
             speed: Keyword.get(params, :speed, 1.0)
           ),
         :ok <- join(sim, context.robot, description, Keyword.get(params, :at), wdf) do
      ref = Process.monitor(sim)
      {:ok, %{sim: sim, robot: context.robot, monitor: ref}}
    end
  end

  defp wdf(%{params: params} = context) do
    case {Keyword.get(params, :world), Map.get(context, :wdf)} do
      {world, wdf} when is_binary(world) and is_binary(wdf) ->
        {:ok, Path.expand(world, Path.dirname(wdf))}

      {world, _} when is_binary(world) ->
        {:ok, Path.expand(world)}

      {nil, wdf} when is_binary(wdf) ->
        {:ok, wdf}

      {nil, _} ->
        {:error, "a simulated robot needs the ADF's wdf: or a world: param (its world)"}

      {other, _} ->
        {:error, "world: #{inspect(other)} is not a path to a WDF"}
    end
  end

  defp join(sim, robot, description, at, wdf) do
    at = at || default_start(sim)

    case Sim.add_robot(sim, robot, description: description, at: at, owner: self()) do
      :ok ->
        :ok

      {:error, message} ->
        if Map.has_key?(Sim.robots(sim), robot),
          do: Sim.attach(sim, robot, self()),
          else: {:error, "#{wdf}: #{message}"}
    end
  end

  defp default_start(sim) do
    case Sim.world(sim).wdf do
      %{waypoints: [first | _]} -> first.name
      _ -> {0.0, 0.0, 0.0}
    end
  end

  @impl true
  def drive(command, state) do
    Sim.command(state.sim, state.robot, command)
    {:ok, state}
  end

  @impl true
  def handle_data({:tc_sim, :readings, robot, readings}, %{robot: robot} = state),
    do: {readings, state}

  # the simulation shut down in order (its node is stopping): a shutdown,
  # not a crash to report
  def handle_data({:DOWN, ref, :process, _pid, reason}, %{monitor: ref})
      when reason in [:shutdown, :normal],
      do: exit({:shutdown, {:simulation_down, reason}})

  def handle_data({:DOWN, ref, :process, _pid, reason}, %{monitor: ref}),
    do: exit({:simulation_down, reason})

  def handle_data(_message, state), do: {[], state}

  @impl true
  def close(_reason, state) do
    Sim.command(state.sim, state.robot, :stop)
    :ok
  end
end
