defmodule ThinkingCap.Testing.Cruise do
  @moduledoc """
  A `ThinkingCap.Sim.Controller` for tests: the robot drives a constant
  command (`command:` arg, default `:stop`) and keeps the latest reading
  of each sensor in its state (`%{command:, readings: %{sensor => payload}}`),
  so a test sees what it sensed with `ThinkingCap.Sim.controller_state/2`.
  """
  @behaviour ThinkingCap.Sim.Controller

  @impl true
  def init(args, _context), do: %{command: Keyword.get(args, :command, :stop), readings: %{}}

  @impl true
  def control(readings, state),
    do: {state.command, %{state | readings: Map.merge(state.readings, readings)}}
end
