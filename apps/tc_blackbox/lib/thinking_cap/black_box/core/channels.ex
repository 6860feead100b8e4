defmodule ThinkingCap.BlackBox.Core.Channels do
  @moduledoc false
  # The channels of one MCAP file being written, for the recorder and the
  # ring buffer's dumps alike. A tuple is written twice: as Foxglove's
  # messages (BlackBox.Foxglove: JSON, with JSON schemas, for Foxglove and
  # the MCAP tools) and whole, in Erlang's external term format
  # (`:erlang.term_to_binary/1`, message encoding "etf", no schema), on
  # `/etf/ID/TAG`, for a replay. The Foxglove messages of large tuples
  # that come many a second (the LPS: 9 KB of JSON, 180 µs, ten a second)
  # are thinned to one a second of the robot's clock (their stamps) per
  # topic; their terms are all kept. A module's trace
  # (ThinkingCap.Runtime.Trace) goes on `/trace/ROBOT/NAME`, callbacks
  # `[{n, us, callback}]` a message ("etf" too), its sequence the
  # first's `n`, `us` each one's time after the message's. A
  # channel (and its schema) is declared in the file on first use.

  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.MCAP.Writer

  defstruct robot: nil,
            terms: true,
            channels: %{},
            schemas: %{},
            # {tag, id} => the channel of its whole terms
            exact: %{},
            # {tag, id} => log time of its last Foxglove message (big tuples)
            json_at: %{}

  @type t :: %__MODULE__{}

  @etf "etf"

  # Foxglove's JSON of these tuples (large, and many a second) is written
  # at most once a `@json_period_ns` of publish time per topic; their
  # whole terms every time
  @big [:lps, :particles, :topology, :segments]
  @json_period_ns 1_000_000_000

  @doc false
  def encoding, do: @etf

  @doc false
  # the tags whose Foxglove messages are thinned, and the period
  def thinned, do: {@big, @json_period_ns / 1.0e9}

  # `terms: false`: Foxglove's messages only (a recording not to replay)
  @spec new(atom(), keyword()) :: t()
  def new(robot, opts \\ []),
    do: %__MODULE__{robot: robot, terms: Keyword.get(opts, :terms, true)}

  # What the blackboard holds of a tuple for the recorder (its batched
  # subscription's `hold:`), made by the tuple's writer: its external
  # term, made once where the tuple is copied anyway, so that the recorder
  # neither copies a large tuple out of the held table nor encodes it.
  # A large, thinned tuple is held without the tuple (its tag, id and
  # stamp say where and when; its term is decoded for its Foxglove
  # message, once a second); any other with it (its Foxglove message is
  # written every time). `write_held/4` writes it.
  @spec held(tuple()) :: tuple()
  def held({tag, id, _payload} = tuple) when tag in @big,
    do: {__MODULE__, :big, tag, id, Foxglove.stamp_ns(tuple), :erlang.term_to_binary(tuple)}

  def held(tuple), do: {__MODULE__, tuple, :erlang.term_to_binary(tuple)}

  # Writes what `held/1` made of a tuple (or a tuple, as `write_tuple/4`).
  @spec write_held(Writer.t(), t(), tuple(), non_neg_integer()) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_held(w, chans, {__MODULE__, :big, tag, id, stamp, etf}, time) do
    publish = stamp || time
    decoded = fn -> Foxglove.messages(:erlang.binary_to_term(etf), time) end
    {messages, chans} = thinned(chans, {tag, id}, publish, decoded)
    # its channel is its tag's and id's (`{tag, id, nil}` stands for the tuple)
    write(w, chans, messages, {tag, id, nil}, etf, time, publish)
  end

  def write_held(w, chans, {__MODULE__, tuple, etf}, time),
    do: write_tuple(w, chans, tuple, etf, time)

  def write_held(w, chans, tuple, time), do: write_tuple(w, chans, tuple, nil, time)

  # Writes `tuple`, received at `time` (ns since the epoch): its Foxglove
  # messages, then the whole term. The count of messages written.
  @spec write_tuple(Writer.t(), t(), tuple(), non_neg_integer()) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_tuple(w, chans, tuple, time), do: write_tuple(w, chans, tuple, nil, time)

  # `etf`: the tuple's external term, or nil to make it here
  defp write_tuple(w, chans, tuple, etf, time) do
    publish = Foxglove.stamp_ns(tuple) || time
    {messages, chans} = foxglove(chans, tuple, time, publish)
    write(w, chans, messages, tuple, etf, time, publish)
  end

  defp write(w, chans, messages, tuple, etf, time, publish) do
    with {:ok, w, chans, n} <- write_all(messages, w, chans, time, publish, 0) do
      if chans.terms,
        do: write_term(w, chans, tuple, etf, time, publish, n),
        else: {:ok, w, chans, n}
    end
  end

  # thinned on the publish time (the robot's clock: a simulation's, which
  # may run slower than the wall's), so that a recording holds the same
  # whatever the speed; a stamp that went back (a new simulation) starts
  # the period again
  defp foxglove(chans, {tag, id, _} = tuple, time, publish) when tag in @big,
    do: thinned(chans, {tag, id}, publish, fn -> Foxglove.messages(tuple, time) end)

  defp foxglove(chans, tuple, time, _publish), do: {Foxglove.messages(tuple, time), chans}

  defp thinned(chans, key, publish, messages) do
    case chans.json_at do
      %{^key => at} when publish - at < @json_period_ns and publish >= at -> {[], chans}
      at -> {messages.(), %{chans | json_at: Map.put(at, key, publish)}}
    end
  end

  defp write_all([], w, chans, _time, _publish, n), do: {:ok, w, chans, n}

  defp write_all([{topic, schema, data} | rest], w, chans, time, publish, n) do
    {channel, w, chans} = channel(w, chans, topic, schema, %{})

    case Writer.add_message(w, channel, time, publish, data, :next) do
      {:ok, w} -> write_all(rest, w, chans, time, publish, n + 1)
      {:error, reason} -> {:error, reason, chans}
    end
  end

  # the whole term on `/etf/ID/TAG`, its channel found by `{tag, id}`
  # (`etf`, its term, made already or made here)
  defp write_term(w, chans, tuple, etf, time, publish, n) do
    key = exact_key(tuple)

    {channel, w, chans} =
      case chans.exact do
        %{^key => channel} ->
          {channel, w, chans}

        _ ->
          {channel, w, chans} = channel(w, chans, exact_topic(tuple), nil, %{})
          {channel, w, %{chans | exact: Map.put(chans.exact, key, channel)}}
      end

    etf = etf || :erlang.term_to_binary(tuple)

    case Writer.add_message(w, channel, time, publish, etf, :next) do
      {:ok, w} -> {:ok, w, chans, n + 1}
      {:error, reason} -> {:error, reason, chans}
    end
  end

  defp exact_key({tag, id, _payload}), do: {tag, id}
  defp exact_key(other), do: {:tuple, tuple_size(other)}

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
