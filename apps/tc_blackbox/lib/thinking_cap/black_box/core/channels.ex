defmodule ThinkingCap.BlackBox.Core.Channels do
  @moduledoc false
  # The channels of one MCAP file being written, for the recorder and the
  # ring buffer's dumps alike. A tuple is written twice: as Foxglove's
  # messages (BlackBox.Foxglove: JSON, with JSON schemas, for Foxglove and
  # the MCAP tools) and whole, in Erlang's external term format
  # (`:erlang.term_to_binary/1`, message encoding "etf", no schema), on
  # `/etf/ID/TAG`, for a replay. A module's trace
  # (ThinkingCap.Runtime.Trace) goes on `/trace/ROBOT/NAME`, callbacks
  # `[{n, us, callback}]` a message ("etf" too), its sequence the
  # first's `n`, `us` each one's time after the message's. A
  # channel (and its schema) is declared in the file on first use.

  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.MCAP.Writer

  defstruct robot: nil, terms: true, channels: %{}, schemas: %{}, sequence: %{}

  @type t :: %__MODULE__{}

  @etf "etf"

  @doc false
  def encoding, do: @etf

  # `terms: false`: Foxglove's messages only (a recording not to replay)
  @spec new(atom(), keyword()) :: t()
  def new(robot, opts \\ []),
    do: %__MODULE__{robot: robot, terms: Keyword.get(opts, :terms, true)}

  # Writes `tuple`, received at `time` (ns since the epoch): its Foxglove
  # messages, then the whole term. The count of messages written.
  @spec write_tuple(Writer.t(), t(), tuple(), non_neg_integer()) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_tuple(w, chans, tuple, time) do
    publish = Foxglove.stamp_ns(tuple) || time

    messages =
      if chans.terms,
        do:
          Foxglove.messages(tuple, time) ++
            [{exact_topic(tuple), nil, :erlang.term_to_binary(tuple)}],
        else: Foxglove.messages(tuple, time)

    Enum.reduce_while(messages, {:ok, w, chans, 0}, fn
      {topic, schema, data}, {:ok, w, chans, n} ->
        {channel, w, chans} = channel(w, chans, topic, schema, %{})
        {sequence, chans} = next(chans, channel)

        case Writer.add_message(w, channel, time, publish, data, sequence) do
          {:ok, w} -> {:cont, {:ok, w, chans, n + 1}}
          {:error, reason} -> {:halt, {:error, reason, chans}}
        end
    end)
  end

  # Writes traced callbacks of module `name`, `[{n, us, callback}]` (its
  # `n`th since init, received `us` after `time`), in one message whose
  # sequence is the first's `n`.
  @spec write_trace(
          Writer.t(),
          t(),
          atom(),
          [{non_neg_integer(), non_neg_integer(), term()}],
          non_neg_integer()
        ) :: {:ok, Writer.t(), t()} | {:error, term(), t()}
  def write_trace(w, chans, name, [{first, _, _} | _] = events, time) do
    topic = trace_topic(chans.robot, name)
    metadata = %{"module" => Atom.to_string(name)}
    {channel, w, chans} = channel(w, chans, topic, nil, metadata)

    case Writer.add_message(w, channel, time, time, :erlang.term_to_binary(events), first) do
      {:ok, w} -> {:ok, w, chans}
      {:error, reason} -> {:error, reason, chans}
    end
  end

  @doc false
  # `/etf/ID/TAG`: beside the Foxglove topic `/ID/TAG`
  @spec exact_topic(tuple()) :: String.t()
  def exact_topic({tag, id, _payload}), do: "/etf" <> Foxglove.topic(id, tag)
  def exact_topic(other), do: "/etf/tuple/#{tuple_size(other)}"

  @doc false
  @spec trace_topic(atom(), atom()) :: String.t()
  def trace_topic(robot, name), do: "/trace" <> Foxglove.topic(robot, name)

  defp next(chans, channel) do
    sequence = Map.get(chans.sequence, channel, 0) + 1
    {sequence, %{chans | sequence: Map.put(chans.sequence, channel, sequence)}}
  end

  # a topic's channel: JSON on its Foxglove schema, or a whole term (no schema)
  defp channel(w, chans, topic, schema, metadata) do
    case chans.channels do
      %{^topic => id} ->
        {id, w, chans}

      _ ->
        {schema_id, w, chans} = schema(w, chans, schema)
        encoding = if schema, do: "json", else: @etf
        metadata = Map.put(metadata, "robot", Atom.to_string(chans.robot))
        {:ok, id, w} = Writer.add_channel(w, schema_id, topic, encoding, metadata)
        {id, w, %{chans | channels: Map.put(chans.channels, topic, id)}}
    end
  end

  defp schema(w, chans, nil), do: {0, w, chans}

  defp schema(w, chans, name) do
    case chans.schemas do
      %{^name => id} ->
        {id, w, chans}

      _ ->
        {:ok, id, w} = Writer.add_schema(w, name, "jsonschema", Foxglove.schema(name))
        {id, w, %{chans | schemas: Map.put(chans.schemas, name, id)}}
    end
  end
end
