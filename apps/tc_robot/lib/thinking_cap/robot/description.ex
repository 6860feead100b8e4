defmodule ThinkingCap.Robot.Description do
  @moduledoc """
  A robot ready to be driven or simulated: its RDF
  (`ThinkingCap.Config.RDF`) with the URDF resolved and the kinematics
  model built.

    * `footprint` - `%{radius: r, polygon: points | nil}`; for a polygon,
      `radius` is its circumscribed radius about the robot frame's origin
      (the distance of its farthest corner), for quick collision checks;
    * `kinematics` - the model struct of `ThinkingCap.Robot.Kinematics.new/1`;
      a differential drive with `urdf:` takes `wheel_radius` and
      `wheel_separation` from the URDF (`ThinkingCap.Robot.URDF.wheels/1`)
      unless the RDF gives them (the RDF wins);
    * `odometry_error` - the RDF's map, for `ThinkingCap.Robot.OdometryError.new/3`;
    * `docking` - the RDF's docking map (tolerances, direction, final leg),
      or `nil` when the RDF has no `docking:` section;
    * `sensors` - the RDF's sensor maps; a sensor with `link:` gets its
      `pose` `{x, y, yaw}` from that URDF link's pose in `base_link`
      (projected on the ground plane), replacing the RDF's `pose`;
    * `circles` - discs `{x, y, r}` in the robot frame that together
      cover the footprint (one disc for a round robot; for a polygon, a row
      of discs along its longer side), for collision checks tighter than
      the circumscribed disc (`circles/1`).

  `urdf` is the loaded `ThinkingCap.Robot.URDF` (or `nil`), `file` the RDF.
  """

  alias ThinkingCap.Config
  alias ThinkingCap.Config.RDF
  alias ThinkingCap.Robot.{Kinematics, URDF}

  defstruct [
    :file,
    :name,
    :footprint,
    :kinematics,
    :odometry_error,
    :docking,
    :urdf,
    sensors: [],
    circles: []
  ]

  @type t :: %__MODULE__{
          file: Path.t() | nil,
          name: String.t(),
          footprint: %{radius: float(), polygon: [{float(), float()}] | nil},
          kinematics: Kinematics.model(),
          odometry_error: map(),
          docking: map() | nil,
          circles: [{float(), float(), float()}],
          urdf: URDF.t() | nil,
          sensors: [map()]
        }

  # the robot frame of a URDF (REP-105)
  @base "base_link"

  @doc "Reads an RDF file (`ThinkingCap.Config.read/1`) and resolves it with `from_rdf/1`."
  @spec load(Path.t()) :: {:ok, t()} | {:error, String.t()}
  def load(rdf_path) do
    case Config.read(rdf_path) do
      {:ok, %RDF{} = rdf} ->
        from_rdf(rdf)

      {:ok, _other} ->
        {:error, "#{rdf_path}: not a robot description (expected a .rdf file)"}

      {:error, errors} ->
        {:error, Config.format_errors(errors)}
    end
  end

  @doc """
  The name of the robot's first sensor of `type` (`:odometry`, `:laser`,
  ...): the tag its readings are published under. `default` when it has
  none, or without a description.
  """
  @spec sensor_name(t() | nil, atom(), atom()) :: atom()
  def sensor_name(nil, _type, default), do: default

  def sensor_name(%__MODULE__{sensors: sensors}, type, default) do
    case Enum.find(sensors, &(&1.type == type)) do
      nil -> default
      sensor -> sensor.name
    end
  end

  @doc """
  Resolves a validated RDF: loads its URDF (if any), fills the wheel
  geometry and the sensors' `link:` poses from it, builds the kinematics
  model. Errors name the RDF file and, for URDF problems, the URDF file.
  """
  @spec from_rdf(RDF.t()) :: {:ok, t()} | {:error, String.t()}
  def from_rdf(%RDF{} = rdf) do
    with {:ok, urdf} <- load_urdf(rdf),
         {:ok, kinematics} <- kinematics(rdf, urdf),
         {:ok, sensors} <- sensors(rdf, urdf) do
      {:ok,
       %__MODULE__{
         file: rdf.file,
         name: rdf.name,
         footprint: footprint(rdf.footprint),
         circles: rdf.footprint |> footprint() |> circles(),
         kinematics: kinematics,
         odometry_error: rdf.odometry_error,
         docking: rdf.docking,
         urdf: urdf,
         sensors: sensors
       }}
    end
  end

  @doc """
  Discs `{x, y, r}` covering a footprint: the disc of a round one; for a
  polygon, its bounding box (in the robot frame) cut along its longer side
  into squares or nearly, each covered by the disc through its corners.
  """
  @spec circles(%{radius: float(), polygon: [{float(), float()}] | nil}) ::
          [{float(), float(), float()}]
  def circles(%{polygon: [_ | _] = polygon}) do
    {xs, ys} = Enum.unzip(polygon)
    {x0, x1, y0, y1} = {Enum.min(xs), Enum.max(xs), Enum.min(ys), Enum.max(ys)}
    along_x = x1 - x0 >= y1 - y0
    {long, short} = if along_x, do: {x1 - x0, y1 - y0}, else: {y1 - y0, x1 - x0}
    n = max(ceil(long / max(short, 1.0e-6)), 1)
    step = long / n
    r = :math.sqrt((short / 2) ** 2 + (step / 2) ** 2)

    for i <- 0..(n - 1) do
      if along_x,
        do: {x0 + step * (i + 0.5), (y0 + y1) / 2, r},
        else: {(x0 + x1) / 2, y0 + step * (i + 0.5), r}
    end
  end

  def circles(%{radius: r}), do: [{0.0, 0.0, r * 1.0}]

  defp load_urdf(%RDF{urdf: nil}), do: {:ok, nil}

  defp load_urdf(%RDF{urdf: path} = rdf) do
    case URDF.load(path) do
      {:ok, urdf} -> {:ok, urdf}
      {:error, errors} -> {:error, "#{rdf.file}: urdf:\n" <> URDF.format_errors(errors)}
    end
  end

  defp kinematics(rdf, urdf) do
    with {:ok, k} <- wheel_geometry(rdf, rdf.kinematics, urdf) do
      {:ok, Kinematics.new(k)}
    end
  rescue
    e in ArgumentError -> {:error, "#{rdf.file}: #{Exception.message(e)}"}
  end

  defp wheel_geometry(rdf, %{type: :differential} = k, %URDF{} = urdf)
       when k.wheel_radius == nil or k.wheel_separation == nil do
    case URDF.wheels(urdf) do
      {:ok, %{radius: r, separation: b}} ->
        {:ok, %{k | wheel_radius: k.wheel_radius || r, wheel_separation: k.wheel_separation || b}}

      {:error, message} ->
        {:error, "#{rdf.file}: kinematics: no wheel_radius/wheel_separation, and #{message}"}
    end
  end

  defp wheel_geometry(_rdf, k, _urdf), do: {:ok, k}

  defp sensors(rdf, urdf) do
    rdf.sensors
    |> Enum.reduce_while({:ok, []}, fn sensor, {:ok, acc} ->
      case sensor_pose(rdf, sensor, urdf) do
        {:ok, sensor} -> {:cont, {:ok, [sensor | acc]}}
        error -> {:halt, error}
      end
    end)
    |> case do
      {:ok, sensors} -> {:ok, Enum.reverse(sensors)}
      error -> error
    end
  end

  defp sensor_pose(rdf, %{link: link} = sensor, urdf) when is_binary(link) do
    with {:urdf, %URDF{}} <- {:urdf, urdf},
         {:ok, {x, y, _z, _roll, _pitch, yaw}} <- URDF.pose(urdf, link, @base) do
      {:ok, %{sensor | pose: {x, y, yaw}}}
    else
      {:urdf, nil} ->
        {:error,
         "#{rdf.file}: sensor #{inspect(sensor.name)}: link: #{inspect(link)} needs a urdf: file"}

      {:error, message} ->
        {:error, "#{rdf.file}: sensor #{inspect(sensor.name)}: link: #{message}"}
    end
  end

  defp sensor_pose(_rdf, sensor, _urdf), do: {:ok, sensor}

  defp footprint(%{polygon: [_ | _] = polygon}) do
    radius = polygon |> Enum.map(fn {x, y} -> :math.sqrt(x * x + y * y) end) |> Enum.max()
    %{radius: radius, polygon: polygon}
  end

  defp footprint(%{radius: r}), do: %{radius: r / 1, polygon: nil}
end
