defmodule ThinkingCap.Dashboard.Foxglove.Channels do
  @moduledoc false
  # The channels a Foxglove session advertises: per robot that published
  # its capabilities, one per laser sensor, its map, its pose estimate and
  # the frame transform of that pose. Topics and schemas are the black
  # box's (ThinkingCap.BlackBox.Foxglove), so a live view and a recording
  # look the same in Foxglove.
  #
  # A channel is `%{id, topic, schema, robot, tag}`: `tag` is the
  # blackboard tag whose tuples feed it.

  alias ThinkingCap.BlackBox.Foxglove, as: Convert

  @type spec :: %{topic: String.t(), schema: String.t(), robot: atom(), tag: atom()}
  @type channel :: %{
          id: pos_integer(),
          topic: String.t(),
          schema: String.t(),
          robot: atom(),
          tag: atom()
        }

  @doc "The channels of robot `id` with capabilities `caps` (without ids)."
  @spec of_robot(atom(), map()) :: [spec()]
  def of_robot(id, caps) do
    lasers =
      for %{type: :laser, name: name} when is_atom(name) <- Map.get(caps, :sensors, []) do
        %{topic: Convert.topic(id, name), schema: "foxglove.LaserScan", robot: id, tag: name}
      end

    lasers ++
      [
        %{topic: Convert.topic(id, :map), schema: "foxglove.Grid", robot: id, tag: :map},
        %{topic: Convert.topic(id, :pose), schema: "foxglove.PoseInFrame", robot: id, tag: :pose},
        %{topic: Convert.topic(id, :tf), schema: "foxglove.FrameTransform", robot: id, tag: :pose}
      ]
  end

  @doc "A channel as the `advertise` operation lists it."
  @spec advertised(channel()) :: map()
  def advertised(channel) do
    %{
      id: channel.id,
      topic: channel.topic,
      encoding: "json",
      schemaName: channel.schema,
      schema: Convert.schema(channel.schema),
      schemaEncoding: "jsonschema"
    }
  end

  @doc """
  The messages a tuple gives, `{topic, schema, json}` (the black box's
  conversion), and its time in nanoseconds: its payload's stamp, else now.
  A tuple whose payload its tag's conversion refuses (a pose `:lost`)
  gives a `thinkingcap.Tuple` on the same topic, which no channel here
  has: a message goes only to a channel of its topic and schema.
  """
  @spec messages(tuple()) :: {non_neg_integer(), [{String.t(), String.t(), iodata()}]}
  def messages(tuple) do
    now = System.os_time(:nanosecond)
    time = Convert.stamp_ns(tuple) || now
    {time, Convert.messages(tuple, now)}
  end
end
