defmodule ThinkingCap.Perception.Fuser do
  @moduledoc """
  Perception as an ADF module: fuses the robot's range sensors (every
  sonar and laser of its RDF) and odometry into the Local Perceptual Space
  (`ThinkingCap.Perception.Fusion`) and publishes it as
  `{:lps, robot, %ThinkingCap.Perception.LPS{}}` (latest value), at most
  every `period` seconds of sensor time (default 0.1).

      perception: [module: ThinkingCap.Perception.Fuser, activity: :event]

  It subscribes itself to the robot's range sensors, its odometry
  (`odometry:` param, default: the RDF's sensor of type `:odometry`, else
  `:odom`) and its estimated pose
  (`{:pose, robot, _}`, which brings in the WDF's walls and doors near
  the robot). Params: `odometry`, `period`, and those of
  `ThinkingCap.Perception.Fusion.new/2` (`resolution`, `window`, `memory`,
  `range`).
  """
  use ThinkingCap.Module

  alias ThinkingCap.Perception.Fusion
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples

  @impl true
  def init(params, context) do
    params = if is_map(params), do: Map.to_list(params), else: params || []
    description = description(context)
    sensors = range_sensors(description)
    {walls, doors} = a_priori(context)

    odometry =
      Keyword.get(params, :odometry, Description.sensor_name(description, :odometry, :odom))

    fusion =
      Fusion.new(
        sensors,
        Keyword.take(params, [:resolution, :window, :memory, :range]) ++
          [walls: walls, doors: doors, robot: context.robot]
      )

    # odometry first, then what else it hears, then the range sensors
    subscriptions =
      for template <-
            [Tuples.reading(odometry, context.robot), Tuples.pose(context.robot)] ++
              for(sensor <- Map.keys(sensors), do: Tuples.reading(sensor, context.robot)),
          do: {:subscribe, template}

    {subscriptions,
     %{
       fusion: fusion,
       robot: context.robot,
       odometry: odometry,
       period: Keyword.get(params, :period, 0.1),
       published: nil
     }}
  end

  @impl true
  def handle_tuple(
        Tuples.reading(tag, robot, %{pose: pose} = p),
        %{robot: robot, odometry: tag} = state
      ),
      do:
        {[], %{state | fusion: Fusion.put_odometry(state.fusion, pose, Map.get(p, :stamp, 0.0))}}

  def handle_tuple(Tuples.pose(robot, %{pose: pose}), %{robot: robot} = state),
    do: {[], %{state | fusion: Fusion.put_world_pose(state.fusion, pose)}}

  def handle_tuple(Tuples.reading(sensor, robot, %{ranges: _} = payload), %{robot: robot} = state) do
    fusion = Fusion.add_reading(state.fusion, sensor, payload)
    state = %{state | fusion: fusion}

    if state.published == nil or fusion.time - state.published >= state.period - 1.0e-9 do
      lps = Fusion.lps(fusion)
      {[out: Tuples.keyed(Tuples.lps(robot, lps))], %{state | published: fusion.time}}
    else
      {[], state}
    end
  end

  def handle_tuple(_tuple, state), do: {[], state}

  defp description(%{rdf: rdf}) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, d} -> d
      {:error, message} -> raise ArgumentError, "perception needs the robot's sensors: #{message}"
    end
  end

  defp description(context),
    do: raise(ArgumentError, "#{inspect(context.name)}: perception needs the ADF's rdf:")

  defp range_sensors(description) do
    for %{type: type} = s <- description.sensors, type in [:laser, :sonar], into: %{} do
      {s.name, Map.take(s, [:type, :pose, :ring_radius, :count, :range, :fov])}
    end
  end

  # the WDF's walls (and obstacle outlines) and doors, world frame
  defp a_priori(%{wdf: wdf}) when is_binary(wdf) do
    case ThinkingCap.Config.read(wdf) do
      {:ok, w} ->
        outlines =
          for %{polygon: p} <- w.obstacles, {a, b} <- Enum.zip(p, tl(p) ++ [hd(p)]), do: {a, b}

        doors =
          for d <- w.doors do
            {{x1, y1}, {x2, y2}} = {d.from, d.to}

            %{
              name: d.name,
              centre: {(x1 + x2) / 2, (y1 + y2) / 2},
              width: :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2),
              heading: :math.atan2(x2 - x1, -(y2 - y1))
            }
          end

        {w.walls ++ outlines, doors}

      {:error, _} ->
        {[], []}
    end
  end

  defp a_priori(_context), do: {[], []}
end
