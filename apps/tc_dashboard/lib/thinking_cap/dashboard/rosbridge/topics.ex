defmodule ThinkingCap.Dashboard.Rosbridge.Topics do
  @moduledoc false
  # The ROS topics rosbridge serves and the blackboard streams behind them
  # (see ThinkingCap.Dashboard.Rosbridge for the table). A topic is a map
  # `%{name, kind, robot, type}`: `robot` is the robot's name (a string,
  # so that a client's words never become atoms) or nil for the global
  # topics (`/tf`, `/tf_static`, `/map`).
  #
  # `robots` everywhere is what the session knows of the robots that
  # published their capabilities: `%{"r1" => %{id: :r1, caps: map}}`.

  alias ThinkingCap.Tuples
  require Tuples

  @robot_kinds %{
    "scan" => {:scan, "sensor_msgs/msg/LaserScan"},
    "odom" => {:odom, "nav_msgs/msg/Odometry"},
    "pose" => {:pose, "geometry_msgs/msg/PoseWithCovarianceStamped"},
    "amcl_pose" => {:pose, "geometry_msgs/msg/PoseWithCovarianceStamped"},
    "map" => {:map, "nav_msgs/msg/OccupancyGrid"},
    "cmd_vel" => {:cmd_vel, "geometry_msgs/msg/Twist"},
    "tf" => {:tf, "tf2_msgs/msg/TFMessage"},
    "tf_static" => {:tf_static, "tf2_msgs/msg/TFMessage"}
  }

  @global_kinds %{
    "tf" => {:tf, "tf2_msgs/msg/TFMessage"},
    "tf_static" => {:tf_static, "tf2_msgs/msg/TFMessage"},
    "map" => {:map, "nav_msgs/msg/OccupancyGrid"}
  }

  # the robot topics that have an un-namespaced alias when there is one robot
  @aliased ~w(scan odom pose amcl_pose cmd_vel)

  @type robots :: %{String.t() => %{id: atom(), caps: map()}}
  @type topic :: %{
          name: String.t(),
          kind: :scan | :odom | :pose | :cmd_vel | :tf | :tf_static | :map,
          robot: String.t() | nil,
          type: String.t()
        }

  @doc "A topic or service name with its leading slash (`rosapi/topics` → `/rosapi/topics`)."
  @spec absolute(String.t()) :: String.t()
  def absolute("/" <> _ = name), do: name
  def absolute(name), do: "/" <> name

  @doc """
  Resolves a client's topic name. `/r1/odom` names robot r1's odometry
  (r1 need not exist yet: its messages come once it does); `/odom` is an
  alias of it while r1 is the only robot.
  """
  @spec resolve(term(), robots()) :: {:ok, topic()} | {:error, String.t()}
  def resolve(name, robots) when is_binary(name) and byte_size(name) <= 256 do
    name = absolute(name)

    case String.split(name, "/", trim: false) do
      ["", kind] when is_map_key(@global_kinds, kind) ->
        {kind, type} = @global_kinds[kind]
        {:ok, %{name: name, kind: kind, robot: nil, type: type}}

      ["", kind] when kind in @aliased ->
        case Map.keys(robots) do
          [robot] ->
            {kind, type} = @robot_kinds[kind]
            {:ok, %{name: name, kind: kind, robot: robot, type: type}}

          [] ->
            {:error, "#{name}: no robot is known yet; name one, as in /r1#{name}"}

          several ->
            {:error,
             "#{name} is ambiguous with #{length(several)} robots; use a namespace, as in /#{hd(Enum.sort(several))}#{name}"}
        end

      ["", robot, kind] when is_map_key(@robot_kinds, kind) ->
        if valid_segment?(robot) do
          {kind, type} = @robot_kinds[kind]
          {:ok, %{name: name, kind: kind, robot: robot, type: type}}
        else
          {:error, "#{inspect(name)} is not a valid topic name"}
        end

      _ ->
        {:error, "unknown topic #{inspect(name)}; /rosapi/topics lists the topics"}
    end
  end

  def resolve(name, _robots) when is_binary(name), do: {:error, "topic name too long"}
  def resolve(nil, _robots), do: {:error, "a topic is required"}

  def resolve(other, _robots),
    do: {:error, "a topic name is a string, not #{inspect(other, limit: 5)}"}

  defp valid_segment?(s), do: Regex.match?(~r/^[A-Za-z_][A-Za-z0-9_]*$/, s)

  @doc "Whether a client's type name (`pkg/Type` or `pkg/msg/Type`) is the topic's type."
  @spec type_matches?(topic(), term()) :: boolean()
  def type_matches?(_topic, type) when type in [nil, ""], do: true

  def type_matches?(topic, type) when is_binary(type),
    do: String.replace(type, "/msg/", "/") == String.replace(topic.type, "/msg/", "/")

  def type_matches?(_topic, _type), do: false

  @doc """
  The topics served, `{name, type}` sorted by name: every robot's, the
  global ones (`/map` only when there is a map: `world?`), and the un-namespaced
  aliases when there is exactly one robot.
  """
  @spec list(robots(), boolean()) :: [{String.t(), String.t()}]
  def list(robots, world?) do
    per_robot =
      for {robot, info} <- robots, kind <- robot_kinds(info.caps) do
        {_, type} = @robot_kinds[kind]
        {"/#{robot}/#{kind}", type}
      end

    aliases =
      case Map.to_list(robots) do
        [{_robot, info}] ->
          for kind <- robot_kinds(info.caps), kind in @aliased do
            {_, type} = @robot_kinds[kind]
            {"/#{kind}", type}
          end

        _ ->
          []
      end

    global =
      for {kind, {_, type}} <- @global_kinds, kind != "map" or world?, do: {"/#{kind}", type}

    Enum.sort(per_robot ++ aliases ++ global)
  end

  # a robot's topics: scan only with a laser, odom only with odometry
  defp robot_kinds(caps) do
    sensors = Map.get(caps, :sensors, [])
    types = Enum.map(sensors, & &1[:type])

    Enum.filter(~w(scan odom pose amcl_pose map cmd_vel tf tf_static), fn
      "scan" -> :laser in types
      "odom" -> :odometry in types
      _ -> true
    end)
  end

  @doc "The blackboard tag of a robot's first sensor of `type`, or `default`."
  @spec sensor_tag(robots(), String.t() | nil, atom(), atom()) :: atom()
  def sensor_tag(robots, robot, type, default) do
    with %{caps: caps} <- robots[robot],
         %{name: name} when is_atom(name) <-
           Enum.find(Map.get(caps, :sensors, []), &(&1[:type] == type)) do
      name
    else
      _ -> default
    end
  end

  @doc """
  The blackboard tags a topic reads (the robot's laser and odometry are
  whatever its capabilities name them; before they are known, `:laser` and
  `:odom`). `/tf_static` reads `:robot`, which every session reads anyway.
  """
  @spec tags(topic(), robots()) :: [atom()]
  def tags(%{kind: :scan, robot: r}, robots), do: [sensor_tag(robots, r, :laser, :laser)]
  def tags(%{kind: :odom, robot: r}, robots), do: [sensor_tag(robots, r, :odometry, :odom)]
  def tags(%{kind: :pose}, _robots), do: [Tuples.tag(:pose)]
  def tags(%{kind: :cmd_vel}, _robots), do: [Tuples.tag(:control)]

  def tags(%{kind: :tf, robot: nil}, robots) do
    odoms = for r <- Map.keys(robots), do: sensor_tag(robots, r, :odometry, :odom)
    Enum.uniq([:odom, Tuples.tag(:pose) | odoms])
  end

  def tags(%{kind: :tf, robot: r}, robots),
    do: Enum.uniq([sensor_tag(robots, r, :odometry, :odom), Tuples.tag(:pose)])

  def tags(%{kind: :tf_static}, _robots), do: [Tuples.tag(:robot)]
  def tags(%{kind: :map}, _robots), do: [Tuples.tag(:map)]

  @doc "Whether a blackboard tuple `{tag, robot, _}` feeds a topic."
  @spec feeds?(topic(), atom(), String.t(), robots()) :: boolean()
  def feeds?(%{robot: r} = _topic, _tag, robot, _robots) when r != nil and r != robot, do: false
  def feeds?(%{kind: :map}, tag, _robot, _robots), do: tag == Tuples.tag(:map)
  def feeds?(%{kind: :tf_static}, tag, _robot, _robots), do: tag == Tuples.tag(:robot)

  def feeds?(%{kind: :tf}, tag, robot, robots),
    do: tag == Tuples.tag(:pose) or tag == sensor_tag(robots, robot, :odometry, :odom)

  def feeds?(topic, tag, _robot, robots), do: tag in tags(topic, robots)
end
