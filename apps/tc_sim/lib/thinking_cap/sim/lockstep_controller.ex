defmodule ThinkingCap.Sim.LockstepController do
  @moduledoc """
  A whole module stack (perception, localization, control, planning: the
  modules of an ADF) as an in-process controller of a simulated robot
  (`ThinkingCap.Sim.Controller`), run in lockstep with the simulation
  clock by `ThinkingCap.Testing.Lockstep`: each step's readings are
  delivered as `{sensor, robot, payload}` tuples (odometry first, so that
  a scan of the step finds the robot's motion up to it), periodic modules are
  released as simulated time passes, and the latest
  `{:drive, robot, %{command: ...}}` is the robot's command. Deterministic
  for a seed, and as fast as the machine: for benchmarks and tests of
  autonomous navigation.

  Args: `modules:` (Lockstep module specs), `rdf:`, `wdf:` (paths given to
  the modules' context).
  """
  @behaviour ThinkingCap.Sim.Controller

  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Tuples
  require Tuples

  @impl true
  def init(args, %{robot: robot}) do
    lock =
      Lockstep.new(
        robot: robot,
        rdf: args[:rdf],
        wdf: args[:wdf],
        modules: Keyword.fetch!(args, :modules)
      )

    %{lock: lock, robot: robot, time: 0.0}
  end

  @impl true
  def control(readings, %{robot: robot} = state) do
    time = readings |> Map.values() |> Enum.map(&Map.get(&1, :stamp, state.time)) |> Enum.max()

    lock =
      readings
      |> Enum.sort_by(fn {_sensor, payload} -> not is_map_key(payload, :pose) end)
      |> Enum.reduce(Lockstep.clear_outs(state.lock), fn {sensor, payload}, lock ->
        Lockstep.deliver(lock, Tuples.reading(sensor, robot, payload))
      end)
      |> Lockstep.advance(time)

    command =
      case Lockstep.latest(lock, Tuples.drive(robot)) do
        Tuples.drive(^robot, %{command: command}) -> command
        nil -> :stop
      end

    {command, %{state | lock: lock, time: time}}
  end
end
