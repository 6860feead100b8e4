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

  @doc """
  Optional: true when `control/2` takes the `ranges` of sonar and laser
  payloads as a binary, one little-endian float64 a reading, in place of
  a list (no list of floats built and collected each step; for
  controllers that only scan them, such as `ThinkingCap.Sim.Wander`).
  A sensor's ranges stay a list when its readings also go to the
  blackboard.
  """
  @callback packed_ranges?() :: boolean()

  @optional_callbacks packed_ranges?: 0

  @doc "Whether `module` takes packed ranges (`c:packed_ranges?/0`)."
  @spec packed_ranges?(module()) :: boolean()
  def packed_ranges?(module) do
    Code.ensure_loaded?(module) and function_exported?(module, :packed_ranges?, 0) and
      module.packed_ranges?() == true
  end
end
