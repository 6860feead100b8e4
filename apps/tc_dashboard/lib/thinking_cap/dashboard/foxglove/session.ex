defmodule ThinkingCap.Dashboard.Foxglove.Session do
  @moduledoc false
  # One Foxglove client's protocol state, apart from the socket
  # (Foxglove.Connection runs it): it opens with `serverInfo` and the
  # channels of the robots known, follows the robots (advertising new ones,
  # unadvertising those whose `{:robot, id, caps}` tuple is gone, checked
  # every @robots_every ms), passes the client's operations to Foxglove.Ops
  # and the blackboard's tuples to Foxglove.Streams.
  #
  # State: channels by id and by topic; robots, each with its caps and
  # channel ids; the client's subscriptions (`%{sub_id => channel_id}`);
  # the blackboard subscriptions by tag; the topics whose message was too
  # big to send (warned once).

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Foxglove.{Channels, Messages, Ops, Streams}
  alias ThinkingCap.Tuples
  require Tuples

  @robots_every 1_000

  @doc "A new session."
  @spec new() :: map()
  def new do
    %{
      channels: %{},
      by_topic: %{},
      robots: %{},
      next_id: 1,
      subs: %{},
      tags: %{},
      too_big: MapSet.new()
    }
  end

  @doc "The first frames: serverInfo and the robots' channels."
  @spec open(map()) :: {[Messages.frame()], map()}
  def open(state) do
    {:ok, ref} = Blackboard.subscribe(Tuples.robot())
    state = %{state | tags: %{robot: ref}}
    Process.send_after(self(), :foxglove_robots, @robots_every)
    session_id = Base.url_encode64(:crypto.strong_rand_bytes(6))
    {frames, state} = follow_robots(state)
    {[Messages.server_info(session_id) | frames], state}
  end

  @doc "A client's text frame."
  @spec handle_text(binary(), map()) :: {[Messages.frame()], map()}
  def handle_text(text, state), do: Ops.handle_text(text, state)

  @doc "A client's binary frame: nothing a client may send in binary is supported."
  @spec handle_binary(binary(), map()) :: {[Messages.frame()], map()}
  def handle_binary(_data, state),
    do: {[Messages.status(:error, "binary operations are not supported by this server")], state}

  @doc "A message to the connection's process."
  @spec handle_info(term(), map()) :: {[Messages.frame()], map()}
  def handle_info({:blackboard, _ref, Tuples.robot(id, caps)}, state)
      when is_atom(id) and is_map(caps),
      do: robot(state, id, caps)

  def handle_info({:blackboard, _ref, {tag, id, _payload} = tuple}, state)
      when is_atom(tag) and is_atom(id),
      do: Streams.publish(state, tuple)

  def handle_info(:foxglove_robots, state) do
    Process.send_after(self(), :foxglove_robots, @robots_every)
    follow_robots(state)
  end

  def handle_info(_message, state), do: {[], state}

  @doc "Ends the session's blackboard subscriptions."
  @spec close(map()) :: :ok
  def close(state) do
    for {_tag, ref} <- state.tags, do: Blackboard.unsubscribe(ref)
    :ok
  end

  # the robots on the blackboard now: new ones advertised, gone ones unadvertised
  defp follow_robots(state) do
    present =
      for Tuples.robot(id, caps) when is_atom(id) and is_map(caps) <-
            Blackboard.rd_all(Tuples.robot()),
          into: %{},
          do: {id, caps}

    {gone, state} =
      state.robots
      |> Map.keys()
      |> Enum.reject(&Map.has_key?(present, &1))
      |> Enum.reduce({[], state}, fn id, {frames, state} ->
        {more, state} = drop_robot(state, id)
        {frames ++ more, state}
      end)

    Enum.reduce(present, {gone, state}, fn {id, caps}, {frames, state} ->
      {more, state} = robot(state, id, caps)
      {frames ++ more, state}
    end)
  end

  # a robot's capabilities: its channels advertised, unless they already are
  defp robot(state, id, caps) do
    specs = Channels.of_robot(id, caps)

    case state.robots[id] do
      %{caps: ^caps} ->
        {[], state}

      %{ids: ids} ->
        if Enum.map(specs, & &1.topic) == Enum.map(ids, &state.channels[&1].topic) do
          {[], put_in(state.robots[id].caps, caps)}
        else
          {dropped, state} = drop_robot(state, id)
          {added, state} = add_robot(state, id, caps, specs)
          {dropped ++ added, state}
        end

      nil ->
        add_robot(state, id, caps, specs)
    end
  end

  defp add_robot(state, id, caps, specs) do
    channels =
      specs
      |> Enum.reject(&Map.has_key?(state.by_topic, &1.topic))
      |> Enum.with_index(state.next_id)
      |> Enum.map(fn {spec, n} -> Map.put(spec, :id, n) end)

    state = %{
      state
      | next_id: state.next_id + length(channels),
        channels: Map.merge(state.channels, Map.new(channels, &{&1.id, &1})),
        by_topic: Map.merge(state.by_topic, Map.new(channels, &{&1.topic, &1.id})),
        robots: Map.put(state.robots, id, %{caps: caps, ids: Enum.map(channels, & &1.id)})
    }

    {if(channels == [], do: [], else: [Messages.advertise(channels)]), state}
  end

  defp drop_robot(state, id) do
    ids = state.robots[id].ids
    topics = for i <- ids, do: state.channels[i].topic

    state = %{
      state
      | channels: Map.drop(state.channels, ids),
        by_topic: Map.drop(state.by_topic, topics),
        robots: Map.delete(state.robots, id),
        subs: Map.reject(state.subs, fn {_sub, channel} -> channel in ids end)
    }

    {if(ids == [], do: [], else: [Messages.unadvertise(ids)]), Streams.sync_tags(state)}
  end
end
