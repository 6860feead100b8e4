defmodule ThinkingCap.Dashboard.Rosbridge.Messages do
  @moduledoc false

  # Blackboard payloads as ROS 2 messages (maps ready for
  # ThinkingCap.Dashboard.Core.JSON), and the one message rosbridge takes in
  # (geometry_msgs/Twist) back. Frames follow REP-103/REP-105: `map`, then
  # per robot `<robot>/odom`, `<robot>/base_link` and one frame per sensor,
  # `<robot>/<sensor name>`. Times are builtin_interfaces/Time
  # (`{sec, nanosec}`) from the payloads' stamps (seconds, the simulator's
  # clock for a simulated robot); a payload without a stamp gets the wall
  # clock's.

  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  alias ThinkingCap.Navigation.OccupancyGrid

  @type pose2d :: {number(), number(), number()}

  ## frames and times

  @doc "The frame of `robot` named `frame` (`\"r1/odom\"`)."
  @spec frame(String.t(), String.t() | atom()) :: String.t()
  def frame(robot, frame), do: "#{robot}/#{frame}"

  @doc "A builtin_interfaces/Time from seconds (nil: now)."
  @spec time(number() | nil) :: %{sec: integer(), nanosec: non_neg_integer()}
  def time(seconds) when is_number(seconds) do
    sec = floor(seconds)
    nanosec = round((seconds - sec) * 1.0e9)

    if nanosec >= 1_000_000_000,
      do: %{sec: sec + 1, nanosec: 0},
      else: %{sec: sec, nanosec: nanosec}
  end

  def time(_none), do: time(System.os_time(:nanosecond) / 1.0e9)

  @doc "A std_msgs/Header."
  @spec header(number() | nil, String.t()) :: map()
  def header(stamp, frame_id), do: %{stamp: time(stamp), frame_id: frame_id}

  ## geometry

  @doc "A quaternion (x, y, z, w) for a rotation of `yaw` about z."
  @spec quaternion(number()) :: map()
  def quaternion(yaw) do
    %{x: 0.0, y: 0.0, z: :math.sin(yaw / 2), w: :math.cos(yaw / 2)}
  end

  @doc "The yaw of a quaternion (its rotation about z; roll and pitch are ignored)."
  @spec yaw(map()) :: float()
  def yaw(%{"x" => x, "y" => y, "z" => z, "w" => w}),
    do: :math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))

  @doc "A geometry_msgs/Pose from a planar pose."
  @spec pose(pose2d()) :: map()
  def pose({x, y, th}),
    do: %{position: %{x: x * 1.0, y: y * 1.0, z: 0.0}, orientation: quaternion(th)}

  @doc "A geometry_msgs/Transform from a planar pose."
  @spec transform(pose2d()) :: map()
  def transform({x, y, th}),
    do: %{translation: %{x: x * 1.0, y: y * 1.0, z: 0.0}, rotation: quaternion(th)}

  @doc "A geometry_msgs/TransformStamped: `child` in `parent` at `pose`."
  @spec transform_stamped(number() | nil, String.t(), String.t(), pose2d()) :: map()
  def transform_stamped(stamp, parent, child, pose),
    do: %{header: header(stamp, parent), child_frame_id: child, transform: transform(pose)}

  @doc """
  The map→odom transform: where the odometry frame lies in the map, given
  the robot's pose in the map (the localizer's estimate) and in the
  odometry frame at the same time: `map_T_odom = map_T_base · (odom_T_base)⁻¹`.
  """
  @spec map_to_odom(pose2d(), pose2d()) :: pose2d()
  def map_to_odom({xm, ym, thm}, {xo, yo, tho}) do
    th = thm - tho
    {c, s} = {:math.cos(th), :math.sin(th)}
    {xm - (c * xo - s * yo), ym - (s * xo + c * yo), normalize_angle(th)}
  end

  @doc """
  A 6×6 covariance (row-major, 36 numbers over x, y, z, roll, pitch, yaw)
  from a planar 3×3 one over x, y, θ; unknown entries are 0.
  """
  @spec covariance6([[number()]] | term()) :: [float()]
  def covariance6([[_, _, _], [_, _, _], [_, _, _]] = c) do
    index = %{0 => 0, 1 => 1, 5 => 2}

    for i <- 0..5, j <- 0..5 do
      with {:ok, a} <- Map.fetch(index, i), {:ok, b} <- Map.fetch(index, j) do
        c |> Enum.at(a) |> Enum.at(b) |> float()
      else
        :error -> 0.0
      end
    end
  end

  def covariance6(_other), do: List.duplicate(0.0, 36)

  ## messages

  @doc """
  A sensor_msgs/LaserScan from a laser payload (`ranges`, `angle_min`,
  `angle_max`, `angle_increment`, `range_min`, `range_max`, `stamp`).
  Ranges that are not numbers (a driver's nil for no echo) become null.
  """
  @spec laser_scan(map(), String.t()) :: map()
  def laser_scan(payload, frame_id) do
    ranges = Map.get(payload, :ranges, [])

    %{
      header: header(payload[:stamp], frame_id),
      angle_min: float(payload[:angle_min]),
      angle_max: float(payload[:angle_max]),
      angle_increment: float(payload[:angle_increment]),
      time_increment: 0.0,
      scan_time: float(payload[:scan_time]),
      range_min: float(payload[:range_min]),
      range_max: float(payload[:range_max]),
      ranges: Enum.map(ranges, &range/1),
      intensities: []
    }
  end

  @doc """
  A nav_msgs/Odometry from an odometry payload (`pose: {x, y, θ}`,
  `twist: {v, ω}`, `stamp`): the pose in `<robot>/odom`, the twist in
  `<robot>/base_link`. Covariances are unknown (zeros).
  """
  @spec odometry(map(), String.t()) :: map()
  def odometry(payload, robot) do
    {v, w} = twist2d(payload[:twist])

    %{
      header: header(payload[:stamp], frame(robot, "odom")),
      child_frame_id: frame(robot, "base_link"),
      pose: %{pose: pose(pose2d(payload[:pose])), covariance: List.duplicate(0.0, 36)},
      twist: %{twist: twist(v, w), covariance: List.duplicate(0.0, 36)}
    }
  end

  @doc """
  A geometry_msgs/PoseWithCovarianceStamped in `map` from the localizer's
  estimate (`pose: {x, y, θ}`, `covariance:` 3×3, `stamp`).
  """
  @spec pose_with_covariance(map()) :: map()
  def pose_with_covariance(payload) do
    %{
      header: header(payload[:stamp], "map"),
      pose: %{pose: pose(pose2d(payload[:pose])), covariance: covariance6(payload[:covariance])}
    }
  end

  @doc "A geometry_msgs/Twist of a planar velocity."
  @spec twist(number(), number()) :: map()
  def twist(v, w),
    do: %{linear: %{x: v * 1.0, y: 0.0, z: 0.0}, angular: %{x: 0.0, y: 0.0, z: w * 1.0}}

  @doc """
  The planar velocity of a geometry_msgs/Twist (decoded JSON): `linear.x`
  and `angular.z`, each within ±100; missing fields are 0 (as ROS fills
  them), anything else is refused.
  """
  @spec from_twist(term()) :: {:ok, {float(), float()}} | {:error, String.t()}
  def from_twist(msg) when is_map(msg) do
    with {:ok, linear} <- vector(msg, "linear"),
         {:ok, angular} <- vector(msg, "angular"),
         {:ok, v} <- component(linear, "linear", "x"),
         {:ok, w} <- component(angular, "angular", "z") do
      {:ok, {v, w}}
    end
  end

  def from_twist(other),
    do: {:error, "a geometry_msgs/Twist is an object, not #{short(other)}"}

  @doc "A tf2_msgs/TFMessage."
  @spec tf_message([map()]) :: map()
  def tf_message(transforms), do: %{transforms: transforms}

  @doc """
  The transforms of one robot on `/tf`: map→odom (from the localizer's
  estimate `pose` against the odometry; identity without an estimate) and
  odom→base_link (the odometry). Nothing without odometry.
  """
  @spec robot_transforms(String.t(), map() | nil, map() | nil) :: [map()]
  def robot_transforms(_robot, nil, _estimate), do: []

  def robot_transforms(robot, odom, estimate) do
    odom_pose = pose2d(odom[:pose])
    stamp = odom[:stamp]

    map_odom =
      case estimate do
        %{pose: {_, _, _} = pose} -> map_to_odom(pose2d(pose), odom_pose)
        _ -> {0.0, 0.0, 0.0}
      end

    [
      transform_stamped(stamp, "map", frame(robot, "odom"), map_odom),
      transform_stamped(stamp, frame(robot, "odom"), frame(robot, "base_link"), odom_pose)
    ]
  end

  @doc """
  The static transforms of one robot (`/tf_static`): base_link→sensor for
  every sensor of its capabilities with a pose (a laser without one sits
  at the base's origin).
  """
  @spec static_transforms(String.t(), map()) :: [map()]
  def static_transforms(robot, capabilities) do
    for sensor <- Map.get(capabilities, :sensors, []),
        pose = sensor_pose(sensor),
        pose != nil do
      transform_stamped(0, frame(robot, "base_link"), frame(robot, sensor[:name]), pose)
    end
  end

  defp sensor_pose(%{pose: {_, _, _} = pose}), do: pose2d(pose)
  defp sensor_pose(%{type: :laser}), do: {0.0, 0.0, 0.0}
  defp sensor_pose(_), do: nil

  @doc """
  A nav_msgs/OccupancyGrid in `map` from cells (one signed byte each, −1
  unknown or 0..100, row-major from the bottom row, as ROS has them).
  """
  @spec occupancy_grid(map()) :: map()
  def occupancy_grid(%{width: w, height: h, resolution: res, origin: origin, data: data}) do
    %{
      header: header(0, "map"),
      info: %{
        map_load_time: time(0),
        resolution: float(res),
        width: w,
        height: h,
        origin: pose(origin)
      },
      data: for(<<v::signed-8 <- data>>, do: v)
    }
  end

  ## the messages of a blackboard tuple

  @doc """
  The messages a blackboard tuple `{tag, robot, payload}` makes on a topic
  it feeds (`Topics.feeds?/4`), each `{stream key, msg}` (the key is the
  robot's name). `latest` holds each robot's newest odometry and
  localizer estimate (`%{{robot, :odom} => payload, {robot, :pose} =>
  payload}`), for `/tf`.
  """
  @spec of_tuple(map(), atom(), String.t(), term(), map()) :: [{String.t(), map()}]
  def of_tuple(%{kind: :scan}, tag, robot, payload, _latest),
    do: [{robot, laser_scan(payload, frame(robot, tag))}]

  def of_tuple(%{kind: :odom}, _tag, robot, payload, _latest),
    do: [{robot, odometry(payload, robot)}]

  def of_tuple(%{kind: :pose}, _tag, robot, payload, _latest),
    do: [{robot, pose_with_covariance(payload)}]

  def of_tuple(%{kind: :cmd_vel}, _tag, robot, payload, _latest) do
    case payload[:command] do
      {:velocity, v, w} when is_number(v) and is_number(w) -> [{robot, twist(v, w)}]
      :stop -> [{robot, twist(0, 0)}]
      _other -> []
    end
  end

  def of_tuple(%{kind: :tf}, _tag, robot, _payload, latest) do
    case latest_transforms(robot, latest) do
      [] -> []
      transforms -> [{robot, tf_message(transforms)}]
    end
  end

  def of_tuple(%{kind: :tf_static}, _tag, robot, caps, _latest) do
    case static_transforms(robot, caps) do
      [] -> []
      transforms -> [{robot, tf_message(transforms)}]
    end
  end

  def of_tuple(%{kind: :map}, :map, robot, %OccupancyGrid{origin: {x, y}} = map, _latest),
    do: [{robot, occupancy_grid(%{map | origin: {x, y, 0.0}})}]

  def of_tuple(_topic, _tag, _robot, _payload, _latest), do: []

  @doc "A robot's `/tf` transforms from the newest odometry and estimate in `latest`."
  @spec latest_transforms(String.t(), map()) :: [map()]
  def latest_transforms(robot, latest),
    do: robot_transforms(robot, latest[{robot, :odom}], latest[{robot, :pose}])

  ## helpers

  defp vector(msg, key) do
    case Map.get(msg, key, %{}) do
      v when is_map(v) -> {:ok, v}
      other -> {:error, "#{key} must be a geometry_msgs/Vector3 object, not #{short(other)}"}
    end
  end

  # a velocity of a robot: at most 100 (m/s or rad/s) either way; a
  # 5,000-digit integer is refused here, not by the arithmetic further on
  defp component(vector, name, key) do
    case Map.get(vector, key, 0) do
      x when is_number(x) and abs(x) <= 100 -> {:ok, x * 1.0}
      x when is_number(x) -> {:error, "#{name}.#{key} must be a number from -100 to 100"}
      other -> {:error, "#{name}.#{key} must be a number, not #{short(other)}"}
    end
  end

  defp short(term), do: inspect(term, limit: 5, printable_limit: 40)

  defp pose2d({x, y, th}) when is_number(x) and is_number(y) and is_number(th),
    do: {x * 1.0, y * 1.0, th * 1.0}

  defp pose2d({x, y}) when is_number(x) and is_number(y), do: {x * 1.0, y * 1.0, 0.0}
  defp pose2d(_), do: {0.0, 0.0, 0.0}

  defp twist2d({v, w}) when is_number(v) and is_number(w), do: {v, w}
  defp twist2d(_), do: {0.0, 0.0}

  defp range(r) when is_number(r), do: r * 1.0
  defp range(_), do: nil

  defp float(x) when is_number(x), do: x * 1.0
  defp float(_), do: 0.0
end
