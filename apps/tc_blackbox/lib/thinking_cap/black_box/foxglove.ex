defmodule ThinkingCap.BlackBox.Foxglove do
  @moduledoc """
  Blackboard tuples as Foxglove messages: JSON (message encoding
  `json`) with JSON schemas (schema encoding `jsonschema`), so that a
  recording opens in Foxglove and the MCAP tools, and the Foxglove
  WebSocket endpoint can send the same messages.

  | tuple | topic | schema |
  |---|---|---|
  | a laser's reading (`ranges`, `angle_min`, `angle_max`) | `/ROBOT/SENSOR` | `foxglove.LaserScan`, frame `ROBOT/base_link`, ranges to the millimetre |
  | `:map` (an `OccupancyGrid`) | `/ROBOT/map` | `foxglove.Grid`, frame `map`, one `INT8` cell per byte |
  | `:pose` (the estimate) | `/ROBOT/pose` and `/ROBOT/tf` | `foxglove.PoseInFrame` in `map`, `foxglove.FrameTransform` `map` → `ROBOT/base_link` |
  | `:sim_pose` (the simulator's truth) | `/ROBOT/sim_pose` | `foxglove.PoseInFrame` in `map` |
  | any other | `/ID/TAG` | `thinkingcap.Tuple`: `tag`, `robot` (the id), `payload` |

  The payload of a `thinkingcap.Tuple` is the term as JSON, whatever it
  holds: atoms as strings, tuples as arrays, structs as objects with
  their `"__struct__"`, binaries that are not UTF-8 as
  `{"base64": ...}`, pids and functions printed. Floats, in every
  message, are written to the millionth from 0.01 up (smaller ones
  whole): the recording keeps the exact terms beside. A Foxglove message's
  `timestamp` is the payload's `stamp` (seconds on the robot's clock)
  when it has one, else the time given.

  Field names follow the `@foxglove/schemas` package (2.x); the schemas
  here are written for this module and hold the fields it fills.
  """

  alias ThinkingCap.BlackBox.Core.JSON
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  @typedoc "A message to record: its topic, its schema's name and its JSON."
  @type message :: {topic :: String.t(), schema :: String.t(), json :: iodata()}

  # foxglove.NumericType
  @int8 2

  # a scan's pose: the robot's frame itself
  @identity ~s({"position":{"x":0.0,"y":0.0,"z":0.0},"orientation":{"x":0,"y":0,"z":0,"w":1}})

  time = %{
    "type" => "object",
    "properties" => %{
      "sec" => %{"type" => "integer", "minimum" => 0},
      "nsec" => %{"type" => "integer", "minimum" => 0, "maximum" => 999_999_999}
    }
  }

  vector3 = %{
    "type" => "object",
    "properties" => Map.new(~w(x y z), &{&1, %{"type" => "number"}})
  }

  quaternion = %{
    "type" => "object",
    "properties" => Map.new(~w(x y z w), &{&1, %{"type" => "number"}})
  }

  pose = %{
    "type" => "object",
    "properties" => %{"position" => vector3, "orientation" => quaternion}
  }

  string = %{"type" => "string"}
  number = %{"type" => "number"}
  numbers = %{"type" => "array", "items" => number}

  schema = fn name, properties ->
    %{"title" => name, "type" => "object", "properties" => properties}
  end

  @schemas %{
    "foxglove.LaserScan" =>
      schema.("foxglove.LaserScan", %{
        "timestamp" => time,
        "frame_id" => string,
        "pose" => pose,
        "start_angle" => number,
        "end_angle" => number,
        "ranges" => numbers,
        "intensities" => numbers
      }),
    "foxglove.Grid" =>
      schema.("foxglove.Grid", %{
        "timestamp" => time,
        "frame_id" => string,
        "pose" => pose,
        "column_count" => %{"type" => "integer", "minimum" => 0},
        "cell_size" => %{
          "type" => "object",
          "properties" => %{"x" => number, "y" => number}
        },
        "row_stride" => %{"type" => "integer", "minimum" => 0},
        "cell_stride" => %{"type" => "integer", "minimum" => 0},
        "fields" => %{
          "type" => "array",
          "items" => %{
            "type" => "object",
            "properties" => %{
              "name" => string,
              "offset" => %{"type" => "integer", "minimum" => 0},
              "type" => %{"type" => "integer", "minimum" => 0, "maximum" => 8}
            }
          }
        },
        "data" => %{"type" => "string", "contentEncoding" => "base64"}
      }),
    "foxglove.PoseInFrame" =>
      schema.("foxglove.PoseInFrame", %{"timestamp" => time, "frame_id" => string, "pose" => pose}),
    "foxglove.FrameTransform" =>
      schema.("foxglove.FrameTransform", %{
        "timestamp" => time,
        "parent_frame_id" => string,
        "child_frame_id" => string,
        "translation" => vector3,
        "rotation" => quaternion
      }),
    "thinkingcap.Tuple" =>
      schema.("thinkingcap.Tuple", %{
        "tag" => string,
        "robot" => string,
        "payload" => %{
          "description" =>
            "the payload as JSON: atoms as strings, tuples as arrays, structs as objects with __struct__"
        }
      })
  }

  @doc "The schemas' names."
  @spec schema_names() :: [String.t()]
  def schema_names, do: Map.keys(@schemas)

  @doc "A schema's JSON schema (schema encoding `jsonschema`)."
  @spec schema(String.t()) :: binary()
  def schema(name), do: @schemas |> Map.fetch!(name) |> :jiffy.encode()

  @doc """
  The messages recording `tuple` gives (one, or two for a pose);
  `time_ns` is the message's time when the payload has no `stamp`.
  """
  @spec messages(tuple(), non_neg_integer()) :: [message()]
  def messages(tuple, time_ns) do
    convert(tuple, time_ns)
  catch
    # a payload of a known tag but an unexpected shape: recorded as it is
    _kind, _reason -> generic(tuple)
  end

  @doc false
  # Which of messages/2's clauses a tuple is for, as far as its tag and
  # its payload's keys tell (the clause checks the rest): `:scan`,
  # `:pose`, `:sim_pose`, `:generic` (surely a `thinkingcap.Tuple`), or
  # nil (a map, or not a `{tag, id, payload}`).
  @spec kind(tuple()) :: :scan | :pose | :sim_pose | :generic | nil
  def kind({:map, _id, _payload}), do: nil
  # a scan's clause takes its angles too (a sonar reading's ranges have none)
  def kind({_tag, _id, %{ranges: _, angle_min: _, angle_max: _}}), do: :scan
  def kind({:pose, _id, _payload}), do: :pose
  def kind({:sim_pose, _id, _payload}), do: :sim_pose
  def kind({_tag, _id, _payload}), do: :generic
  def kind(_other), do: nil

  @doc false
  # The topics and schemas of the messages of a tuple of `kind` (as
  # `kind/1` says, and of the shape its clause takes), in order.
  @spec topics(:scan | :pose | :sim_pose | :generic, term(), term()) :: [{String.t(), String.t()}]
  def topics(:scan, tag, id), do: [{topic(id, tag), "foxglove.LaserScan"}]

  def topics(:pose, _tag, id),
    do: [{topic(id, :pose), "foxglove.PoseInFrame"}, {topic(id, :tf), "foxglove.FrameTransform"}]

  def topics(:sim_pose, _tag, id), do: [{topic(id, :sim_pose), "foxglove.PoseInFrame"}]
  def topics(:generic, tag, id), do: [{topic(id, tag), "thinkingcap.Tuple"}]

  defp convert(
         Tuples.reading(sensor, robot, %{ranges: ranges, angle_min: a0, angle_max: a1} = scan),
         time_ns
       )
       when is_list(ranges) and is_number(a0) and is_number(a1) and is_atom(robot) do
    json = [
      "{\"timestamp\":",
      timestamp(scan, time_ns),
      ",\"frame_id\":",
      JSON.string(frame(robot)),
      ",\"pose\":",
      @identity,
      ",\"start_angle\":",
      JSON.number(a0),
      ",\"end_angle\":",
      JSON.number(a1),
      ",\"ranges\":",
      millimetres(ranges),
      ",\"intensities\":[]}"
    ]

    [{topic(robot, sensor), "foxglove.LaserScan", json}]
  end

  defp convert(Tuples.map(robot, %OccupancyGrid{} = grid), time_ns) do
    {x, y} = grid.origin

    json = [
      "{\"timestamp\":",
      timestamp(grid, time_ns),
      ",\"frame_id\":\"map\",\"pose\":{\"position\":",
      point(x, y),
      ",\"orientation\":{\"x\":0,\"y\":0,\"z\":0,\"w\":1}},\"column_count\":",
      JSON.number(grid.width),
      ",\"cell_size\":{\"x\":",
      JSON.number(grid.resolution),
      ",\"y\":",
      JSON.number(grid.resolution),
      "},\"row_stride\":",
      JSON.number(grid.width),
      ",\"cell_stride\":1,\"fields\":[{\"name\":\"occupancy\",\"offset\":0,\"type\":",
      Integer.to_string(@int8),
      "}],\"data\":\"",
      Base.encode64(grid.data),
      "\"}"
    ]

    [{topic(robot, :map), "foxglove.Grid", json}]
  end

  defp convert(Tuples.pose(robot, %{pose: {x, y, theta}} = estimate), time_ns)
       when is_number(x) and is_number(y) and is_number(theta) do
    stamp = timestamp(estimate, time_ns)
    q = yaw(theta)
    position = point(x, y)

    pose = [
      "{\"timestamp\":",
      stamp,
      ",\"frame_id\":\"map\",\"pose\":{\"position\":",
      position,
      ",\"orientation\":",
      q,
      "}}"
    ]

    transform = [
      "{\"timestamp\":",
      stamp,
      ",\"parent_frame_id\":\"map\",\"child_frame_id\":",
      JSON.string(frame(robot)),
      ",\"translation\":",
      position,
      ",\"rotation\":",
      q,
      ?}
    ]

    [
      {topic(robot, :pose), "foxglove.PoseInFrame", pose},
      {topic(robot, :tf), "foxglove.FrameTransform", transform}
    ]
  end

  defp convert(Tuples.sim_pose(robot, %{pose: {x, y, theta}} = truth), time_ns)
       when is_number(x) and is_number(y) and is_number(theta) do
    pose = [
      "{\"timestamp\":",
      timestamp(truth, time_ns),
      ",\"frame_id\":\"map\",\"pose\":{\"position\":",
      point(x, y),
      ",\"orientation\":",
      yaw(theta),
      "}}"
    ]

    [{topic(robot, :sim_pose), "foxglove.PoseInFrame", pose}]
  end

  defp convert(tuple, _time_ns), do: generic(tuple)

  defp generic({tag, id, payload}) do
    # in C, into one binary, when it can (the same bytes)
    json =
      case JSON.Native.tuple(tag, id, payload) do
        false -> generic_json(tag, id, payload)
        json -> json
      end

    [{topic(id, tag), "thinkingcap.Tuple", json}]
  end

  defp generic(other) do
    json = ["{\"tag\":null,\"robot\":null,\"payload\":", JSON.value(other), ?}]
    [{"/tuple/#{tuple_size(other)}", "thinkingcap.Tuple", json}]
  end

  @doc false
  # a thinkingcap.Tuple message's JSON written in Erlang (`generic/1`
  # writes it in C when it can; the tests compare the two)
  @spec generic_json(term(), term(), term()) :: iodata()
  def generic_json(tag, id, payload) do
    [
      "{\"tag\":",
      JSON.value(tag),
      ",\"robot\":",
      JSON.value(id),
      ",\"payload\":",
      JSON.fast(payload),
      ?}
    ]
  end

  defp frame(robot), do: Atom.to_string(robot) <> "/base_link"

  # A scan's ranges to the millimetre: shorter JSON, quicker to write and
  # to compress than every digit of a double (the exact ones are in the
  # recording's terms). A range that is not a number raises (the scan is
  # then recorded as it is).
  # Written in C, into one binary (`Core.JSON.Native`).
  defp millimetres(ranges), do: JSON.Native.millimetres(ranges)

  @doc """
  The stamp of a tuple's payload in nanoseconds (its `stamp:` in
  seconds), or nil when it has none.
  """
  @spec stamp_ns(tuple()) :: non_neg_integer() | nil
  def stamp_ns({_tag, _id, %{stamp: stamp}}) when is_number(stamp) and stamp >= 0,
    do: round(stamp * 1.0e9)

  def stamp_ns(_tuple), do: nil

  @doc "A topic's name: `/ID/TAG` (ids and tags printed as they are, atoms without the colon)."
  @spec topic(term(), term()) :: String.t()
  def topic(id, tag), do: "/" <> name(id) <> "/" <> name(tag)

  defp name(a) when is_atom(a), do: Atom.to_string(a)
  defp name(s) when is_binary(s), do: if(String.valid?(s), do: s, else: inspect(s))
  defp name(other), do: inspect(other)

  defp timestamp(%{stamp: stamp}, _time_ns) when is_number(stamp) and stamp >= 0,
    do: time(round(stamp * 1.0e9))

  defp timestamp(_payload, time_ns), do: time(time_ns)

  defp time(ns),
    do: [
      "{\"sec\":",
      Integer.to_string(div(ns, 1_000_000_000)),
      ",\"nsec\":",
      Integer.to_string(rem(ns, 1_000_000_000)),
      ?}
    ]

  defp point(x, y), do: ["{\"x\":", JSON.number(x), ",\"y\":", JSON.number(y), ",\"z\":0.0}"]

  # a rotation by theta about z, as a quaternion
  defp yaw(theta) do
    [
      "{\"x\":0.0,\"y\":0.0,\"z\":",
      JSON.number(:math.sin(theta / 2)),
      ",\"w\":",
      JSON.number(:math.cos(theta / 2)),
      ?}
    ]
  end
end
