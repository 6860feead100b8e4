defmodule ThinkingCap.Sim.LockstepControllerTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim.LockstepController
  alias ThinkingCap.Testing.Lockstep

  defmodule Recorder do
    @moduledoc false
    use ThinkingCap.Module

    @impl true
    def init(_params, context), do: {[subscribe: {:_, context.robot, :_}], []}

    @impl true
    def handle_tuple({tag, _robot, _payload}, seen), do: {[], seen ++ [tag]}
  end

  test "a step's odometry reaches the modules before its other readings" do
    state = LockstepController.init([modules: [rec: {Recorder, []}]], %{robot: :r})

    readings = %{
      bumper: %{pressed: false, stamp: 0.05},
      laser: %{ranges: [1.0], stamp: 0.05},
      odom: %{pose: {0.0, 0.0, 0.0}, stamp: 0.05},
      sonar: %{ranges: [1.0], stamp: 0.05}
    }

    {:stop, state} = LockstepController.control(readings, state)
    assert [:odom | rest] = Lockstep.state(state.lock, :rec)
    assert Enum.sort(rest) == [:bumper, :laser, :sonar]
  end
end
