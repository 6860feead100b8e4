defmodule ThinkingCap.Sim.Controller do
  @moduledoc """
  A controller that runs inside the simulation, next to its robot, as
  Stage's controllers do: no blackboard round trip, deterministic for a
  seed. For benchmarks, tests and crowds of background robots; the robots
  of an ADF are driven through the blackboard instead.

  `control/2` is called with the readings of every step at which some
  sensor read (a map `sensor => payload`, see `ThinkingCap.Sim`) and
  answers with the robot's next command.
  """

  @doc "The controller's first state; `info` has `:robot` and `:description`."
  @callback init(args :: term(), info :: %{robot: atom(), description: struct()}) :: term()

  @doc "The next command, from fresh readings."
  @callback control(readings :: %{atom() => map()}, state :: term()) ::
              {ThinkingCap.Robot.command(), term()}
end
