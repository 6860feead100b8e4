defmodule ThinkingCap.Dashboard.Rosbridge.Snapshot do
  @moduledoc false
  # What a subscription sends at once: its topic's latest values, read
  # from the blackboard (the streams are latest-value tuples). And the
  # newest odometry and localizer estimate of each robot a session keeps
  # for `/tf` (`latest`: `%{{robot, :odom} => payload, {robot, :pose} =>
  # payload}`).

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Tuples
  require Tuples
  alias ThinkingCap.Dashboard.Rosbridge.{Messages, Topics, WorldMap}
  alias ThinkingCap.Navigation.OccupancyGrid

  @doc """
  The messages a new subscription to `topic` sends at once, each `{stream
  key, msg}`, and `latest` with what it read for them. `world` is the
  dashboard's world, `/map`'s fallback.
  """
  @spec initial(Topics.topic(), Topics.robots(), term(), map()) ::
          {:ok, [{String.t() | nil, map()}], map()} | {:error, String.t()}
  def initial(%{kind: :map, robot: only} = topic, _robots, world, latest) do
    # a request that has no map to send (or only an error) costs nothing
    nothing = world == nil and Blackboard.rdp(Tuples.map()) == :none

    if nothing or WorldMap.allow_send?(),
      do: initial_map(topic, only, world, latest),
      else: {:error, "too many map requests on this node just now: try again in a second"}
  end

  def initial(%{kind: :tf, robot: only} = topic, robots, _world, latest) do
    latest = prime(topic, robots, latest)

    messages =
      for {name, _info} <- robots,
          only == nil or only == name,
          transforms = Messages.latest_transforms(name, latest),
          transforms != [],
          do: {name, Messages.tf_message(transforms)}

    {:ok, messages, latest}
  end

  def initial(%{kind: :tf_static, robot: only}, robots, _world, latest) do
    messages =
      for {name, %{caps: caps}} <- robots,
          only == nil or only == name,
          transforms = Messages.static_transforms(name, caps),
          transforms != [],
          do: {name, Messages.tf_message(transforms)}

    {:ok, messages, latest}
  end

  def initial(topic, robots, _world, latest) do
    messages =
      for tag <- Topics.tags(topic, robots),
          {^tag, id, payload} when is_atom(id) and is_map(payload) <-
            Blackboard.rd_all({tag, :_, :_}),
          robot = Atom.to_string(id),
          Topics.feeds?(topic, tag, robot, robots),
          message <- Messages.of_tuple(topic, tag, robot, payload, latest),
          do: message

    {:ok, messages, latest}
  end

  # the map a robot learned (ThinkingCap.Navigation.Mapper), else the world's
  defp initial_map(topic, only, world, latest) do
    learned =
      for Tuples.map(id, %OccupancyGrid{} = map) <- Blackboard.rd_all(Tuples.map()),
          robot = to_string(id),
          only == nil or only == robot,
          message <- Messages.of_tuple(topic, :map, robot, map, latest),
          do: message

    case {learned, only} do
      {[_ | _], _} ->
        {:ok, learned, latest}

      {[], nil} ->
        case WorldMap.cells(world) do
          {:ok, cells} -> {:ok, [{nil, Messages.occupancy_grid(cells)}], latest}
          {:error, reason} -> {:error, reason}
        end

      {[], _robot} ->
        {:ok, [], latest}
    end
  end

  # `latest` with the newest tuples on the blackboard that `topic` reads
  defp prime(topic, robots, latest) do
    Enum.reduce(Topics.tags(topic, robots), latest, fn tag, latest ->
      Enum.reduce(Blackboard.rd_all({tag, :_, :_}), latest, fn
        {^tag, id, payload}, latest when is_atom(id) and is_map(payload) ->
          remember(latest, robots, tag, Atom.to_string(id), payload)

        _, latest ->
          latest
      end)
    end)
  end

  @doc "`latest` with a tuple's payload when it is a robot's estimate or odometry."
  @spec remember(map(), Topics.robots(), atom(), String.t(), term()) :: map()
  def remember(latest, _robots, :pose, robot, payload),
    do: Map.put(latest, {robot, :pose}, payload)

  def remember(latest, robots, tag, robot, payload) do
    if tag == Topics.sensor_tag(robots, robot, :odometry, :odom),
      do: Map.put(latest, {robot, :odom}, payload),
      else: latest
  end
end
