defmodule ThinkingCap.Dashboard.Rosbridge.Definitions do
  @moduledoc false
  # The ROS 2 message definitions of the types rosbridge serves, in the
  # `.msg` syntax, written out from the interfaces' documented fields (no
  # comments, no constants). `full_text/1` gives what rosapi's
  # `topics_and_raw_types` answers: the type's definition followed by each
  # type it uses, each after a line of 80 `=` and `MSG: pkg/Type`, which is
  # how clients such as Foxglove learn to parse messages they have no
  # definitions for.

  @separator String.duplicate("=", 80)

  @msgs %{
    "builtin_interfaces/Time" => "int32 sec\nuint32 nanosec",
    "std_msgs/Header" => "builtin_interfaces/Time stamp\nstring frame_id",
    "geometry_msgs/Vector3" => "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Point" => "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/Quaternion" => "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/Pose" => "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation",
    "geometry_msgs/PoseWithCovariance" => "geometry_msgs/Pose pose\nfloat64[36] covariance",
    "geometry_msgs/PoseWithCovarianceStamped" =>
      "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose",
    "geometry_msgs/Twist" => "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular",
    "geometry_msgs/TwistWithCovariance" => "geometry_msgs/Twist twist\nfloat64[36] covariance",
    "geometry_msgs/Transform" =>
      "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation",
    "geometry_msgs/TransformStamped" =>
      "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform",
    "sensor_msgs/LaserScan" =>
      Enum.join(
        [
          "std_msgs/Header header",
          "float32 angle_min",
          "float32 angle_max",
          "float32 angle_increment",
          "float32 time_increment",
          "float32 scan_time",
          "float32 range_min",
          "float32 range_max",
          "float32[] ranges",
          "float32[] intensities"
        ],
        "\n"
      ),
    "nav_msgs/Odometry" =>
      Enum.join(
        [
          "std_msgs/Header header",
          "string child_frame_id",
          "geometry_msgs/PoseWithCovariance pose",
          "geometry_msgs/TwistWithCovariance twist"
        ],
        "\n"
      ),
    "nav_msgs/MapMetaData" =>
      Enum.join(
        [
          "builtin_interfaces/Time map_load_time",
          "float32 resolution",
          "uint32 width",
          "uint32 height",
          "geometry_msgs/Pose origin"
        ],
        "\n"
      ),
    "nav_msgs/OccupancyGrid" => "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data",
    "tf2_msgs/TFMessage" => "geometry_msgs/TransformStamped[] transforms"
  }

  @doc "The short name of a type (`pkg/msg/Type` and `pkg/Type` → `pkg/Type`)."
  @spec short(String.t()) :: String.t()
  def short(type), do: String.replace(type, "/msg/", "/")

  @doc "Whether a type is one of ours."
  @spec known?(String.t()) :: boolean()
  def known?(type), do: Map.has_key?(@msgs, short(type))

  @doc "The full text of a type's definition with every type it uses; nil if unknown."
  @spec full_text(String.t()) :: String.t() | nil
  def full_text(type) do
    type = short(type)

    if Map.has_key?(@msgs, type) do
      deps = type |> dependencies([]) |> Enum.reverse() |> tl()

      Enum.map_join(
        [@msgs[type] | Enum.map(deps, &"#{@separator}\nMSG: #{&1}\n#{@msgs[&1]}")],
        "\n",
        & &1
      )
    end
  end

  # every complex type used, depth first, each once, `type` first
  defp dependencies(type, seen) do
    if type in seen do
      seen
    else
      @msgs[type]
      |> String.split("\n")
      |> Enum.map(fn line ->
        line |> String.split(" ") |> hd() |> String.replace(~r/\[\d*\]$/, "")
      end)
      |> Enum.filter(&Map.has_key?(@msgs, &1))
      |> Enum.reduce([type | seen], &dependencies/2)
    end
  end
end
