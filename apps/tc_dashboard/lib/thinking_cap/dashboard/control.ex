defmodule ThinkingCap.Dashboard.Control do
  @moduledoc """
  The controlling actions of the dashboard and of rosbridge, as blackboard
  writes the robot base (`ThinkingCap.Robot`) and the planner act on:

    * `teleop/4` writes `{:teleop, robot, %{command: {:velocity, v, w}, by:,
      sent_at:}}`, clamped to the robot's limits (its published
      capabilities, from the RDF). The base drives it while it is refreshed
      within 300 ms (the deadman rule) and over autonomy;
    * `teleop_release/2` hands control back at once;
    * `estop/2` and `estop_release/2` latch and release the E-stop;
    * `goal/2` gives the planner a go-to task;
    * `restart/1` restarts a module through `ThinkingCap.Runtime`.

  Callers check the access rights; these functions check the arguments.
  """

  alias ThinkingCap.Dashboard.Core.RestartLimit
  alias ThinkingCap.Blackboard

  @type robot :: atom()

  @doc "The robots that published their capabilities."
  @spec robots() :: [robot()]
  def robots do
    for {:robot, id, _caps} <- Blackboard.rd_all({:robot, :_, :_}), do: id
  end

  @doc "Looks up a robot by its name (a string from a client), among the known robots."
  @spec robot(String.t() | atom()) :: {:ok, robot()} | {:error, String.t()}
  def robot(name) when is_atom(name) and not is_nil(name) do
    if name in robots(), do: {:ok, name}, else: {:error, "no robot #{inspect(name)}"}
  end

  def robot(name) when is_binary(name) do
    case Enum.find(robots(), &(Atom.to_string(&1) == name)) do
      nil -> {:error, "no robot #{inspect(name)}"}
      id -> {:ok, id}
    end
  end

  def robot(other), do: {:error, "a robot name is a string, not #{inspect(other)}"}

  @doc """
  Drives `robot` by hand at `v` m/s and `w` rad/s (clamped to its limits).
  Options: `by:` who (shown on the page), `sent_at:` the client's clock
  when the command left it (epoch ms, echoed back in `{:control, ...}`).
  """
  @spec teleop(robot(), number(), number(), keyword()) ::
          {:ok, {float(), float()}} | {:error, String.t()}
  def teleop(robot, v, w, opts \\ [])

  def teleop(robot, v, w, opts) when is_number(v) and is_number(w) do
    with {:ok, limits} <- limits(robot) do
      v = clamp(v * 1.0, limits[:max_speed])
      w = clamp(w * 1.0, limits[:max_turn_rate])

      Blackboard.out(
        {:teleop, robot,
         %{command: {:velocity, v, w}, by: opts[:by], sent_at: number(opts[:sent_at])}},
        key: {:teleop, robot}
      )

      {:ok, {v, w}}
    end
  end

  def teleop(_robot, v, w, _opts),
    do: {:error, "speeds must be numbers, got #{inspect(v)} and #{inspect(w)}"}

  @doc "Ends teleoperation of `robot` now."
  @spec teleop_release(robot(), term()) :: :ok
  def teleop_release(robot, by \\ nil) do
    Blackboard.out({:teleop, robot, %{command: :release, by: by}}, key: {:teleop, robot})
  end

  @doc "Latches `robot`'s E-stop: it stops and stays stopped until released."
  @spec estop(robot(), term()) :: :ok
  def estop(robot, by \\ nil) do
    Blackboard.out(
      {:estop, robot, %{engaged: true, by: by, at: System.os_time(:millisecond)}},
      key: {:estop, robot}
    )
  end

  @doc "Releases `robot`'s E-stop."
  @spec estop_release(robot(), term()) :: :ok
  def estop_release(robot, by \\ nil) do
    Blackboard.out(
      {:estop, robot, %{engaged: false, by: by, at: System.os_time(:millisecond)}},
      key: {:estop, robot}
    )
  end

  @doc "Sends `robot` to a point `{x, y}` or a named waypoint (a go-to task for its planner)."
  @spec goal(robot(), {number(), number()} | atom()) :: :ok
  def goal(robot, {x, y} = target) when is_number(x) and is_number(y) do
    Blackboard.out({:task, robot, %{task: {:go_to, target}}}, key: {:task, robot})
  end

  def goal(robot, waypoint) when is_atom(waypoint) do
    Blackboard.out({:task, robot, %{task: {:go_to, waypoint}}}, key: {:task, robot})
  end

  @doc """
  Restarts a running module by its ADF name (a string from a client, or an
  atom), of `robot` when given. Without a robot, a name that two robots'
  modules share is refused, naming them. Restarts are rate limited, all
  clients together (a module at most once every 5 s, 20 a minute in all):
  the runtime's module supervisor gives up after 100 restarts in 10 s.
  """
  @spec restart(String.t() | atom(), String.t() | atom() | nil) :: :ok | {:error, String.t()}
  def restart(name, robot \\ nil) do
    running =
      ThinkingCap.Runtime.which_modules()
      |> Enum.filter(&(to_string(&1.name) == to_string(name)))
      |> Enum.filter(&(robot == nil or to_string(&1.robot) == to_string(robot)))
      |> Enum.uniq_by(& &1.robot)

    case running do
      [] ->
        {:error, "no module #{inspect(name)} is running#{if robot, do: " for robot #{robot}"}"}

      [%{name: name, robot: robot}] ->
        with :ok <- RestartLimit.admit({robot, name}) do
          case ThinkingCap.Runtime.restart({robot, name}) do
            :ok -> :ok
            {:error, :not_running} -> {:error, "module #{name} stopped meanwhile"}
          end
        end

      several ->
        {:error,
         "module #{name} runs for robots #{Enum.map_join(several, ", ", & &1.robot)}: name the robot"}
    end
  end

  defp limits(robot) do
    case Blackboard.rdp({:robot, robot, :_}) do
      {:ok, {:robot, ^robot, caps}} -> {:ok, Map.get(caps, :limits, %{})}
      :none -> {:error, "no robot #{inspect(robot)}"}
    end
  end

  defp clamp(x, max) when is_number(max) and max > 0, do: x |> max(-max) |> min(max)
  defp clamp(x, _), do: x

  defp number(x) when is_number(x), do: x
  defp number(_), do: nil
end
