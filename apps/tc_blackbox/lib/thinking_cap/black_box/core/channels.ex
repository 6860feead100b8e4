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

  alias ThinkingCap.BlackBox.Core.JSON.Native
  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.MCAP.Writer

  defstruct robot: nil,
            terms: true,
            channels: %{},
            schemas: %{},
            # {tag, id} => the channel of its whole terms
            exact: %{},
            # {tag, id} => log time of its last Foxglove message (big tuples)
            json_at: %{},
            # {kind, tag, id} => {its Foxglove messages' channels, its terms'}
            # (Foxglove.kind/1: the tuples held as their terms)
            kinds: %{}

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
  # message, once a second); so is a tuple whose Foxglove messages are
  # read from its term, in C (a thinkingcap.Tuple, a scan, a pose: its
  # kind, Foxglove.kind/1); any other with it (a map). `write_held/4`
  # writes it.
  @spec held(tuple()) :: tuple()
  def held({tag, id, _payload} = tuple) when tag in @big,
    do: {__MODULE__, :big, tag, id, Foxglove.stamp_ns(tuple), :erlang.term_to_binary(tuple)}

  def held({tag, id, _payload} = tuple) do
    case Foxglove.kind(tuple) do
      nil -> {__MODULE__, tuple, :erlang.term_to_binary(tuple)}
      kind -> {__MODULE__, kind, tag, id, Foxglove.stamp_ns(tuple), :erlang.term_to_binary(tuple)}
    end
  end

  def held(tuple), do: {__MODULE__, tuple, :erlang.term_to_binary(tuple)}

  # Writes what `held/1` made of a tuple (or a tuple, as `write_tuple/4`).
  @spec write_held(Writer.t(), t(), tuple(), non_neg_integer()) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_held(w, chans, held, time), do: write_held_all(w, chans, [{held, time}])

  # Writes what `held/1` made of tuples (or tuples), `[{held, time}]`
  # oldest first, as `write_held/4` each. A run of those held as their
  # kinds' terms goes to C in one call (`Writer.add_held/2`: their JSON
  # made from the terms straight into the chunk), their channels found
  # (and declared) first; the others' messages are made here, a run's
  # records in one call (`Writer.add_messages/3`). The count of messages
  # written.
  @spec write_held_all(Writer.t(), t(), [{tuple(), non_neg_integer()}]) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_held_all(w, chans, entries), do: write_runs(entries, w, chans, 0)

  defp write_runs([], w, chans, n), do: {:ok, w, chans, n}

  defp write_runs([{{__MODULE__, kind, _, _, _, _}, _} | _] = entries, w, chans, n)
       when kind != :big do
    case kind_items(entries, chans, []) do
      {[], [entry | rest]} -> write_first(entry, w, chans, n) |> next_run(rest)
      {items, rest} -> write_kinds(items, w, chans, n) |> next_run(rest)
    end
  end

  defp write_runs(entries, w, chans, n) do
    {others, rest} = Enum.split_while(entries, &(not held_as_kind?(&1)))
    {w, chans, messages, bytes, k} = held_all(others, {w, chans, [], 0, 0})

    case Writer.add_messages(w, :lists.reverse(messages), bytes) do
      {:ok, w} -> write_runs(rest, w, chans, n + k)
      {:error, reason} -> {:error, reason, chans}
    end
  end

  defp held_as_kind?({{__MODULE__, kind, _, _, _, _}, _}), do: kind != :big
  defp held_as_kind?(_entry), do: false

  defp next_run({:ok, w, chans, n}, rest), do: write_runs(rest, w, chans, n)
  defp next_run(error, _rest), do: error

  # the tuples held as their kinds' terms whose channels are known, until
  # one that is not, as Writer.add_held/2 takes them (`Compression.held/0`)
  defp kind_items([{{__MODULE__, kind, tag, id, stamp, etf}, time} | rest] = entries, chans, acc)
       when kind != :big do
    case chans.kinds do
      %{{^kind, ^tag, ^id} => {channels, term_channel}} ->
        kind_items(rest, chans, [{channels, term_channel, time, stamp || time, kind, etf} | acc])

      _ ->
        {:lists.reverse(acc), entries}
    end
  end

  defp kind_items(rest, _chans, acc), do: {:lists.reverse(acc), rest}

  # The first of its kind, tag and id: its channels are declared when C
  # writes its JSON (as it will the next ones'), else it is written as a
  # tuple, on the channels its messages name
  defp write_first({{__MODULE__, kind, tag, id, stamp, etf}, time}, w, chans, n) do
    if Native.messages_etf(kind, etf, stamp || time) do
      {channels, term_channel, w, chans} = kind_channels(w, chans, kind, tag, id)
      write_kinds([{channels, term_channel, time, stamp || time, kind, etf}], w, chans, n)
    else
      write_decoded(etf, time, w, chans, n)
    end
  end

  # written in C; one whose JSON C leaves (a term Core.JSON writes
  # otherwise) is decoded and written here, as a tuple
  defp write_kinds(items, w, chans, n) do
    case Writer.add_held(w, items) do
      {:ok, w, k, []} ->
        {:ok, w, chans, n + k}

      {:ok, w, k, [{_, _, time, _, _, etf} | rest]} ->
        case write_decoded(etf, time, w, chans, n + k) do
          {:ok, w, chans, n} -> write_kinds(rest, w, chans, n)
          error -> error
        end

      {:error, reason} ->
        {:error, reason, chans}
    end
  end

  defp write_decoded(etf, time, w, chans, n) do
    {w, chans, messages, bytes, k} =
      tuple(:erlang.binary_to_term(etf), etf, time, {w, chans, [], 0, 0})

    case Writer.add_messages(w, :lists.reverse(messages), bytes) do
      {:ok, w} -> {:ok, w, chans, n + k}
      {:error, reason} -> {:error, reason, chans}
    end
  end

  # Writes `tuple`, received at `time` (ns since the epoch): its Foxglove
  # messages, then the whole term. The count of messages written.
  @spec write_tuple(Writer.t(), t(), tuple(), non_neg_integer()) ::
          {:ok, Writer.t(), t(), non_neg_integer()} | {:error, term(), t()}
  def write_tuple(w, chans, tuple, time), do: write_held_all(w, chans, [{tuple, time}])

  # The messages to write, newest first, with the writer and channels
  # (channels are declared as they are first used) and the bytes of the
  # messages' binaries, and their count: {w, chans, messages, bytes, n}
  defp held_all([], acc), do: acc
  defp held_all([{held, time} | rest], acc), do: held_all(rest, held(held, time, acc))

  defp held({__MODULE__, :big, tag, id, stamp, etf}, time, {w, chans, ms, bytes, n}) do
    publish = stamp || time
    decoded = fn -> Foxglove.messages(:erlang.binary_to_term(etf), time) end
    {messages, chans} = thinned(chans, {tag, id}, publish, decoded)
    # its channel is its tag's and id's (`{tag, id, nil}` stands for the tuple)
    queue(messages, {tag, id, nil}, etf, time, publish, {w, chans, ms, bytes, n})
  end

  defp held({__MODULE__, tuple, etf}, time, acc), do: tuple(tuple, etf, time, acc)
  defp held(tuple, time, acc), do: tuple(tuple, nil, time, acc)

  # `etf`: the tuple's external term, or nil to make it here
  defp tuple(tuple, etf, time, {w, chans, ms, bytes, n}) do
    publish = Foxglove.stamp_ns(tuple) || time
    {messages, chans} = foxglove(chans, tuple, time, publish)
    queue(messages, tuple, etf, time, publish, {w, chans, ms, bytes, n})
  end

  # its Foxglove messages, then its whole term
  defp queue(messages, tuple, etf, time, publish, acc) do
    {w, chans, ms, bytes, n} = queue_json(messages, time, publish, acc)

    if chans.terms,
      do: queue_term(tuple, etf, time, publish, {w, chans, ms, bytes, n}),
      else: {w, chans, ms, bytes, n}
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

  defp queue_json([], _time, _publish, acc), do: acc

  defp queue_json([{topic, schema, data} | rest], time, publish, {w, chans, ms, bytes, n}) do
    {channel, w, chans} = channel(w, chans, topic, schema, %{})
    ms = [{channel, :next, time, publish, data} | ms]
    queue_json(rest, time, publish, {w, chans, ms, bytes + binary_bytes(data), n + 1})
  end

  # the whole term on `/etf/ID/TAG`, its channel found by `{tag, id}`
  # (`etf`, its term, made already or made here)
  defp queue_term(tuple, etf, time, publish, {w, chans, ms, bytes, n}) do
    {channel, w, chans} = exact_channel(w, chans, tuple)
    etf = etf || :erlang.term_to_binary(tuple)
    {w, chans, [{channel, :next, time, publish, etf} | ms], bytes + byte_size(etf), n + 1}
  end

  defp exact_channel(w, chans, tuple) do
    key = exact_key(tuple)

    case chans.exact do
      %{^key => channel} ->
        {channel, w, chans}

      _ ->
        {channel, w, chans} = channel(w, chans, exact_topic(tuple), nil, %{})
        {channel, w, %{chans | exact: Map.put(chans.exact, key, channel)}}
    end
  end

  # the channels of a tuple of `kind` (Foxglove.kind/1): its Foxglove
  # messages' and its term's, found by its kind, tag and id (declared in
  # order on first use, as `queue/6` would)
  defp kind_channels(w, chans, kind, tag, id) do
    key = {kind, tag, id}

    case chans.kinds do
      %{^key => {channels, term_channel}} ->
        {channels, term_channel, w, chans}

      _ ->
        {channels, {w, chans}} =
          Enum.map_reduce(Foxglove.topics(kind, tag, id), {w, chans}, fn {topic, schema},
                                                                         {w, chans} ->
            {channel, w, chans} = channel(w, chans, topic, schema, %{})
            {channel, {w, chans}}
          end)

        {term_channel, w, chans} =
          if chans.terms, do: exact_channel(w, chans, {tag, id, nil}), else: {nil, w, chans}

        kinds = Map.put(chans.kinds, key, {channels, term_channel})
        {channels, term_channel, w, %{chans | kinds: kinds}}
    end
  end

  # what decides a call's scheduler (Compression.messages/3): a binary's
  # bytes; iodata (a few small JSON messages) counts as none, as it did
  # for Compression.message/6
  defp binary_bytes(data) when is_binary(data), do: byte_size(data)
  defp binary_bytes(_iodata), do: 0

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

  # a topic's channel: JSON on its Foxglove schema, or a whole term (no
  # schema). One per topic and schema: a tuple whose payload its kind's
  # writer refuses (a pose `:lost`) is a `thinkingcap.Tuple` on the topic
  # of its kind's messages, on a channel of its own, so that every
  # channel's messages are of its schema
  defp channel(w, chans, topic, schema, metadata) do
    key = {topic, schema}

    case chans.channels do
      %{^key => id} ->
        {id, w, chans}

      _ ->
        {schema_id, w, chans} = schema(w, chans, schema)
        encoding = if schema, do: "json", else: @etf
        metadata = Map.put(metadata, "robot", Atom.to_string(chans.robot))
        {:ok, id, w} = Writer.add_channel(w, schema_id, topic, encoding, metadata)
        {id, w, %{chans | channels: Map.put(chans.channels, key, id)}}
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
