defmodule ThinkingCap.Sim.Wanderer do
  @moduledoc """
  `ThinkingCap.Sim.Wander` as an ADF module: safe wandering through the
  blackboard, for any robot, simulated or real, until the cognitive layer
  drives it. Subscribe it (in the ADF) to the robot's laser or sonar and
  bumper; each reading gives a `{:drive, robot, %{command: ...}}` tuple,
  which the robot's driver follows.

      wander: [module: ThinkingCap.Sim.Wanderer, activity: :event,
               subscribe: [{:laser, :r1, :_}, {:bumper, :r1, :_}]]

  Params are those of `ThinkingCap.Sim.Wander`.
  """
  use ThinkingCap.Module

  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim.Wander
  alias ThinkingCap.Tuples
  require Tuples

  @impl true
  def init(params, context) do
    params = if is_map(params), do: Map.to_list(params), else: params || []

    case Description.load(context.rdf || "") do
      {:ok, description} ->
        {:ok,
         %{
           robot: context.robot,
           wander: Wander.init(params, %{robot: context.robot, description: description})
         }}

      {:error, message} ->
        raise ArgumentError, "#{inspect(context.name)}: needs the ADF's rdf: #{message}"
    end
  end

  @impl true
  def handle_tuple(Tuples.reading(sensor, robot, payload), %{robot: robot} = state)
      when is_map(payload) do
    {command, wander} = Wander.control(%{sensor => payload}, state.wander)
    {[out: Tuples.keyed(Tuples.drive(robot, %{command: command}))], %{state | wander: wander}}
  end

  def handle_tuple(_tuple, state), do: {[], state}
end
