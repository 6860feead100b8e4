defmodule ThinkingCap.Dashboard.Rosbridge.Driving do
  @moduledoc false
  # The robots a rosbridge session drives through /cmd_vel: it takes them
  # by teleoperation (`ThinkingCap.Dashboard.Control`) as `by`, and hands
  # them back when it unadvertises /cmd_vel or goes, unless someone else
  # has taken them meanwhile.

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Tuples
  require Tuples
  alias ThinkingCap.Dashboard.Control

  @doc "The id of the robot named `name`: a known robot's, else one on the blackboard."
  @spec robot_id(String.t(), ThinkingCap.Dashboard.Rosbridge.Topics.robots()) ::
          {:ok, atom()} | {:error, String.t()}
  def robot_id(name, robots) do
    case robots[name] do
      %{id: id} -> {:ok, id}
      nil -> Control.robot(name)
    end
  end

  @doc "Hands back the robot named `robot_name` if `driven` has it; the robots still driven."
  @spec stop(MapSet.t(atom()), String.t(), String.t()) :: MapSet.t(atom())
  def stop(driven, robot_name, by) do
    case Enum.find(driven, &(Atom.to_string(&1) == robot_name)) do
      nil ->
        driven

      robot ->
        release(robot, by)
        MapSet.delete(driven, robot)
    end
  end

  @doc "Hands `robot` back, unless someone else has taken it meanwhile."
  @spec release(atom(), String.t()) :: :ok
  def release(robot, by) do
    case Blackboard.rdp(Tuples.teleop(robot)) do
      {:ok, Tuples.teleop(^robot, %{by: ^by, command: {:velocity, _, _}})} ->
        Control.teleop_release(robot, by)

      _ ->
        :ok
    end
  end
end
