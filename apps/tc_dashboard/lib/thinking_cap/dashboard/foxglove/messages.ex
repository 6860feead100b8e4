defmodule ThinkingCap.Dashboard.Foxglove.Messages do
  @moduledoc false
  # The frames a Foxglove session sends: JSON text frames for the
  # operations, binary frames for the messages (opcode 0x01, the
  # subscription id as a little-endian uint32, the time in nanoseconds as a
  # little-endian uint64, then the JSON payload).

  alias ThinkingCap.Dashboard.Foxglove.Channels

  @type frame :: {:text, iodata()} | {:binary, iodata()}

  # foxglove.StatusLevel
  @levels %{info: 0, warning: 1, error: 2}

  @doc "The `serverInfo` operation, first on every connection."
  @spec server_info(String.t()) :: frame()
  def server_info(session_id) do
    json(%{
      op: "serverInfo",
      name: "ThinkingCap",
      capabilities: [],
      supportedEncodings: ["json"],
      metadata: %{},
      sessionId: session_id
    })
  end

  @doc "The `advertise` operation for `channels`."
  @spec advertise([Channels.channel()]) :: frame()
  def advertise(channels),
    do: json(%{op: "advertise", channels: Enum.map(channels, &Channels.advertised/1)})

  @doc "The `unadvertise` operation for channel ids."
  @spec unadvertise([pos_integer()]) :: frame()
  def unadvertise(ids), do: json(%{op: "unadvertise", channelIds: ids})

  @doc "A `status` operation."
  @spec status(:info | :warning | :error, String.t()) :: frame()
  def status(level, message), do: json(%{op: "status", level: @levels[level], message: message})

  @doc "A `messageData` binary frame."
  @spec message_data(non_neg_integer(), non_neg_integer(), iodata()) :: frame()
  def message_data(subscription, time_ns, payload),
    do: {:binary, [<<1, subscription::little-32, time_ns::little-64>>, payload]}

  defp json(map), do: {:text, :jiffy.encode(map)}
end
