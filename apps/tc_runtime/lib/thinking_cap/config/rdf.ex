defmodule ThinkingCap.Config.RDF do
  @footprint_fields [
    radius: {:pos_number, doc: "a round robot's radius, m"},
    polygon: {{:list, :point}, doc: "corners in the robot frame, m (at least 3)"}
  ]

  @kinematics_fields [
    type: {{:one_of, [:differential, :tricycle, :ackermann]}, required: true, doc: "drive"},
    wheel_radius: {:pos_number, doc: "m (differential: required unless given by urdf:)"},
    wheel_separation:
      {:pos_number,
       doc: "m between the drive wheels (differential: required unless given by urdf:)"},
    wheelbase:
      {:pos_number, doc: "m from rear axle to steered wheel(s) (tricycle, ackermann: required)"},
    track: {:pos_number, doc: "m between the steered wheels (ackermann: required)"},
    max_steering: {:pos_number, doc: "rad (tricycle, ackermann: required)"},
    max_speed: {:pos_number, default: 1.0, doc: "m/s"},
    max_turn_rate: {:pos_number, default: 1.5, doc: "rad/s"},
    max_acceleration: {:pos_number, default: 1.0, doc: "m/s²"}
  ]

  @docking_fields [
    position_tolerance:
      {:pos_number, default: 0.1, doc: "how near the dock's point the robot must stop, m"},
    heading_tolerance:
      {:pos_number, default: 0.1, doc: "how near the dock's heading the robot must stop, rad"},
    direction:
      {{:one_of, [:forward, :reverse]},
       default: :forward, doc: "driving into the dock forwards or in reverse (forks first)"},
    approach: {:pos_number, default: 1.5, doc: "the straight final leg into the dock, m"},
    speed: {:pos_number, default: 0.2, doc: "speed on the final leg, m/s"}
  ]

  @odometry_fields [
    wheel_diameter_ratio:
      {:pos_number, default: 1.0, doc: "right/left wheel diameter (systematic error)"},
    wheelbase_ratio:
      {:pos_number, default: 1.0, doc: "actual/nominal wheelbase (systematic error)"},
    slip: {:non_neg_number, default: 0.0, doc: "std. dev. of distance error per metre driven"},
    turn_slip:
      {:non_neg_number, default: 0.0, doc: "std. dev. of heading error per radian turned"}
  ]

  @noise_fields [
    stddev: {:non_neg_number, default: 0.0, doc: "additive Gaussian noise, m (or rad)"},
    proportional: {:non_neg_number, default: 0.0, doc: "noise growing with range, fraction"},
    miss_probability: {:probability, default: 0.0, doc: "chance a reading or detection is missed"}
  ]

  @fault_fields [
    type:
      {{:one_of, [:stuck, :dropout, :spikes, :drift, :dead]}, required: true, doc: "fault model"},
    probability:
      {:probability, default: 1.0, doc: "per reading (spikes, dropout) or of being faulty at all"},
    magnitude: {:number, default: 0.0, doc: "spike size, m; drift rate, m/s"},
    after:
      {:non_neg_number, default: 0.0, doc: "seconds of simulated time before the fault starts"}
  ]

  @sensor_fields [
    name:
      {:atom,
       required: true, doc: "unique name; readings are published as `{name, robot, payload}`"},
    type:
      {{:one_of, [:sonar, :laser, :beacon_laser, :bumper, :odometry]},
       required: true, doc: "sensor kind"},
    pose: {:pose, default: {0.0, 0.0, 0.0}, doc: "in the robot frame (for a ring: its centre)"},
    link:
      {:string,
       doc:
         "URDF link giving the sensor's pose (needs urdf:); replaces pose: when the URDF is read"},
    count: {:pos_integer, default: 1, doc: "transducers in a ring, evenly spaced"},
    ring_radius: {:non_neg_number, default: 0.0, doc: "ring radius, m"},
    range: {:range, doc: "{min, max} m (sonar, laser, beacon_laser: required)"},
    fov: {:pos_number, doc: "field of view, rad (sonar cone, laser sweep; required there)"},
    beams: {:pos_integer, doc: "laser beams (laser: required)"},
    rays: {:pos_integer, default: 5, doc: "rays sampling a sonar cone"},
    max_reflections: {:non_neg_integer, default: 2, doc: "specular bounces a sonar ray may make"},
    critical_angle:
      {:pos_number,
       default: 0.26, doc: "sonar incidence angle, rad, beyond which surfaces reflect"},
    rate: {:pos_number, default: 10.0, doc: "readings per second"},
    crosstalk:
      {:boolean, default: false, doc: "sonar ring: a transducer may hear its neighbours' echoes"},
    noise: {{:keyword, @noise_fields}, default: [], doc: "noise model (below)"},
    faults: {{:list, {:keyword, @fault_fields}}, default: [], doc: "fault models (below)"}
  ]

  @fields [
    name: {:string, required: true, doc: "the robot model"},
    urdf: {:path, doc: "a URDF file for sensor poses and wheel geometry, relative to this file"},
    footprint:
      {{:keyword, @footprint_fields}, required: true, doc: "give `radius` or `polygon` (below)"},
    kinematics: {{:keyword, @kinematics_fields}, required: true, doc: "drive and limits (below)"},
    odometry_error:
      {{:keyword, @odometry_fields}, default: [], doc: "odometry error model (below)"},
    docking:
      {{:keyword, @docking_fields},
       doc: "how it docks at waypoints with a heading (below); none: position only"},
    sensors: {{:list, {:keyword, @sensor_fields}}, default: [], doc: "each sensor (below)"}
  ]

  @moduledoc """
  The robot description file (`*.rdf`): footprint, kinematics and their
  limits, sensors with their noise and fault models, odometry error. Units
  are SI (m, rad, s); frames follow REP-103 (x forward, y left).

  ## Top-level keys

  #{ThinkingCap.Config.Schema.describe(@fields)}

  ## Footprint keys

  #{ThinkingCap.Config.Schema.describe(@footprint_fields)}

  ## Kinematics keys

  #{ThinkingCap.Config.Schema.describe(@kinematics_fields)}

  ## Docking keys

  #{ThinkingCap.Config.Schema.describe(@docking_fields)}

  ## Odometry error keys

  #{ThinkingCap.Config.Schema.describe(@odometry_fields)}

  ## Sensor keys

  #{ThinkingCap.Config.Schema.describe(@sensor_fields)}

  ## Noise keys

  #{ThinkingCap.Config.Schema.describe(@noise_fields)}

  ## Fault keys

  #{ThinkingCap.Config.Schema.describe(@fault_fields)}
  """

  alias ThinkingCap.Config.Schema

  defstruct [
    :file,
    :name,
    :urdf,
    :footprint,
    :kinematics,
    :odometry_error,
    :docking,
    sensors: []
  ]

  @type t :: %__MODULE__{
          file: Path.t(),
          name: String.t(),
          urdf: Path.t() | nil,
          footprint: map(),
          kinematics: map(),
          odometry_error: map(),
          docking: map() | nil,
          sensors: [map()]
        }

  @required_by_drive %{
    differential: [:wheel_radius, :wheel_separation],
    tricycle: [:wheelbase, :max_steering],
    ackermann: [:wheelbase, :track, :max_steering]
  }

  @doc false
  @spec from_data(term(), Path.t(), map()) ::
          {:ok, t()} | {:error, [ThinkingCap.Config.Error.t()]}
  def from_data(data, file, positions) do
    {value, st} = Schema.start(data, @fields, file, positions)

    st =
      st
      |> check_footprint(value[:footprint])
      |> check_kinematics(value[:kinematics], value[:urdf])
      |> check_sensors(value[:sensors] || [], value[:urdf])
      |> check_urdf(file, value[:urdf])

    case Schema.errors(st) do
      [] ->
        urdf = if value.urdf, do: Path.expand(value.urdf, Path.dirname(file))

        {:ok,
         %__MODULE__{
           file: file,
           name: value.name,
           urdf: urdf,
           footprint: value.footprint,
           kinematics: value.kinematics,
           odometry_error: value.odometry_error,
           docking: value[:docking],
           sensors: value.sensors
         }}

      errors ->
        {:error, errors}
    end
  end

  defp check_footprint(st, nil), do: st

  defp check_footprint(st, %{radius: r, polygon: p}) do
    case {r, p} do
      {nil, nil} ->
        Schema.error(st, [:footprint], "footprint: give radius: metres or polygon: [{x, y}, ...]")

      {nil, p} when length(p) < 3 ->
        Schema.error(st, [:footprint, :polygon], "footprint.polygon: needs at least 3 points")

      {_r, nil} ->
        st

      {nil, _p} ->
        st

      _ ->
        Schema.error(st, [:footprint], "footprint: give radius or polygon, not both")
    end
  end

  # the URDF gives a differential drive's wheel geometry (ThinkingCap.Robot.URDF.wheels/1)
  @from_urdf %{differential: [:wheel_radius, :wheel_separation], tricycle: [], ackermann: []}

  defp check_kinematics(st, %{type: type} = k, urdf) when is_map_key(@required_by_drive, type) do
    required =
      if is_binary(urdf),
        do: @required_by_drive[type] -- @from_urdf[type],
        else: @required_by_drive[type]

    Enum.reduce(required, st, fn key, st ->
      if Map.get(k, key),
        do: st,
        else:
          Schema.error(
            st,
            [:kinematics],
            "kinematics: a #{type} drive needs #{key}: (#{doc_of(key)})"
          )
    end)
  end

  defp check_kinematics(st, _k, _urdf), do: st

  defp doc_of(key), do: elem(@kinematics_fields[key], 1)[:doc]

  defp check_sensors(st, sensors, urdf) do
    {st, _seen} =
      sensors
      |> Enum.with_index()
      |> Enum.reduce({st, MapSet.new()}, fn {s, i}, {st, seen} ->
        path = [:sensors, i]
        # a name that failed its own check is reported already
        name = Map.get(s, :name)

        st =
          if name != nil and MapSet.member?(seen, name),
            do:
              Schema.error(
                st,
                path ++ [:name],
                "sensors[#{i}].name: #{inspect(name)} is used by another sensor"
              ),
            else: st

        {st |> check_sensor(path, s) |> check_link(path, s, urdf), MapSet.put(seen, name)}
      end)

    st
  end

  @needs %{
    sonar: [:range, :fov],
    laser: [:range, :fov, :beams],
    beacon_laser: [:range, :fov],
    bumper: [],
    odometry: []
  }

  defp check_sensor(st, path, %{type: type} = s) when is_map_key(@needs, type) do
    Enum.reduce(@needs[type], st, fn key, st ->
      if Map.get(s, key),
        do: st,
        else:
          Schema.error(st, path, "#{Schema.path_string(path)}: a #{type} sensor needs #{key}:")
    end)
  end

  defp check_sensor(st, _path, _s), do: st

  defp check_link(st, path, %{link: link} = s, nil) when is_binary(link),
    do:
      Schema.error(
        st,
        path ++ [:link],
        "#{Schema.path_string(path ++ [:link])}: sensor #{inspect(Map.get(s, :name))} takes its pose from URDF link #{inspect(link)}, but the robot has no urdf: file"
      )

  defp check_link(st, _path, _s, _urdf), do: st

  defp check_urdf(st, file, urdf) when is_binary(urdf) do
    path = Path.expand(urdf, Path.dirname(file))
    if File.regular?(path), do: st, else: Schema.error(st, [:urdf], "urdf: no such file #{path}")
  end

  defp check_urdf(st, _file, _urdf), do: st
end
