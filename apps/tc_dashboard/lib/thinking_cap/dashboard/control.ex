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
    * `restart/1` restarts a module through `ThinkingCap.Runtime`;
    * `params/1` and `set_param/5` read and set modules' live parameters
      (`ThinkingCap.Runtime.set_param/4`), with values from a client's JSON.

  Callers check the access rights; these functions check the arguments.
  """

  alias ThinkingCap.Dashboard.Core.RestartLimit
  alias ThinkingCap.Blackboard
  alias ThinkingCap.Tuples
  require Tuples

  @type robot :: atom()

  @doc "The robots that published their capabilities."
  @spec robots() :: [robot()]
  def robots do
    for Tuples.robot(id, _caps) <- Blackboard.rd_all(Tuples.robot()), do: id
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

      out(
        Tuples.teleop(robot, %{
          command: {:velocity, v, w},
          by: opts[:by],
          sent_at: number(opts[:sent_at])
        })
      )

      {:ok, {v, w}}
    end
  end

  def teleop(_robot, v, w, _opts),
    do: {:error, "speeds must be numbers, got #{inspect(v)} and #{inspect(w)}"}

  @doc "Ends teleoperation of `robot` now."
  @spec teleop_release(robot(), term()) :: :ok
  def teleop_release(robot, by \\ nil) do
    out(Tuples.teleop(robot, %{command: :release, by: by}))
  end

  @doc "Latches `robot`'s E-stop: it stops and stays stopped until released."
  @spec estop(robot(), term()) :: :ok
  def estop(robot, by \\ nil) do
    out(Tuples.estop_engaged(robot, by))
  end

  @doc "Releases `robot`'s E-stop."
  @spec estop_release(robot(), term()) :: :ok
  def estop_release(robot, by \\ nil) do
    out(Tuples.estop_released(robot, by))
  end

  @doc "Sends `robot` to a point `{x, y}` or a named waypoint (a go-to task for its planner)."
  @spec goal(robot(), {number(), number()} | atom()) :: :ok
  def goal(robot, {x, y} = target) when is_number(x) and is_number(y) do
    out(Tuples.task(robot, %{task: {:go_to, target}}))
  end

  def goal(robot, waypoint) when is_atom(waypoint) do
    out(Tuples.task(robot, %{task: {:go_to, waypoint}}))
  end

  @doc """
  Restarts a running module by its ADF name (a string from a client, or an
  atom), of `robot` when given. Without a robot, a name that two robots'
  modules share is refused, naming them. Restarts are rate limited, all
  clients together (a module at most once every 5 s, 20 a minute in all):
  the module is down (its fallback holding) while it restarts. Restarts
  asked for do not count against the restart intensity of the module's
  layer (`ThinkingCap.Runtime.Supervision`): no client can make a layer
  give up.
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
            {:error, reason} -> {:error, "module #{name} did not restart: #{inspect(reason)}"}
          end
        end

      several ->
        {:error,
         "module #{name} runs for robots #{Enum.map_join(several, ", ", & &1.robot)}: name the robot"}
    end
  end

  @doc """
  The params of every running module of `robot` that declares some
  (`ThinkingCap.Runtime.describe_params/1`), by module name.
  """
  @spec params(robot()) :: [ThinkingCap.Runtime.params_info()]
  def params(robot) do
    for %{robot: ^robot, name: name} <- ThinkingCap.Runtime.which_modules(),
        {:ok, %{fields: [_ | _]} = info} <- [ThinkingCap.Runtime.describe_params({robot, name})],
        do: info
  end

  @doc """
  Sets param `key` of `robot`'s running module `name` (strings from a
  client) to `value` as JSON gave it: a choice's name becomes the choice
  (never a new atom), and params of types a form cannot give (`input:
  :other`) are refused. Then the runtime checks it against the module's
  schema (`ThinkingCap.Runtime.set_param/4`, `by:` who): the error says
  why not (the range, the type, read-only).
  """
  @spec set_param(robot(), String.t(), String.t(), term(), term()) :: :ok | {:error, String.t()}
  def set_param(robot, name, key, value, by \\ nil) do
    with {:ok, info} <- running(robot, name),
         {:ok, field} <- field(info, key),
         {:ok, value} <- from_json(field, value) do
      ThinkingCap.Runtime.set_param({robot, info.name}, field.key, value, by: by)
    end
  end

  defp running(robot, name) do
    case Enum.find(
           ThinkingCap.Runtime.which_modules(),
           &(&1.robot == robot and to_string(&1.name) == name)
         ) do
      nil -> {:error, "no module #{inspect(name)} is running for robot #{robot}"}
      %{name: name} -> ThinkingCap.Runtime.describe_params({robot, name})
    end
  end

  defp field(info, key) do
    case Enum.find(info.fields, &(Atom.to_string(&1.key) == key)) do
      nil ->
        known = Enum.map_join(info.fields, ", ", & &1.key)
        known = if known == "", do: "it declares none", else: "its params: #{known}"
        {:error, "module #{info.name} has no param #{inspect(key)} (#{known})"}

      field ->
        {:ok, field}
    end
  end

  defp from_json(%{input: :choice, choices: choices} = field, value) when is_binary(value) do
    case Enum.find(choices, &(to_string(&1) == value)) do
      nil ->
        {:error,
         "#{field.key}: expected one of #{Enum.map_join(choices, ", ", &to_string/1)}, got #{inspect(value, printable_limit: 40)}"}

      choice ->
        {:ok, choice}
    end
  end

  defp from_json(%{input: :other} = field, _value),
    do: {:error, "#{field.key} (#{field.type}) cannot be set from the dashboard"}

  defp from_json(_field, value) when is_map(value) or is_list(value),
    do: {:error, "a param's value is a number, a boolean or a string"}

  defp from_json(_field, value), do: {:ok, value}

  # the latest per robot (Tuples.key/1)
  defp out(tuple) do
    {tuple, opts} = Tuples.keyed(tuple)
    Blackboard.out(tuple, opts)
  end

  defp limits(robot) do
    case Blackboard.rdp(Tuples.robot(robot)) do
      {:ok, Tuples.robot(^robot, caps)} -> {:ok, Map.get(caps, :limits, %{})}
      :none -> {:error, "no robot #{inspect(robot)}"}
    end
  end

  defp clamp(x, max) when is_number(max) and max > 0, do: x |> max(-max) |> min(max)
  defp clamp(x, _), do: x

  defp number(x) when is_number(x), do: x
  defp number(_), do: nil
end
