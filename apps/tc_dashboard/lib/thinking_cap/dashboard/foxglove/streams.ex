defmodule ThinkingCap.Dashboard.Foxglove.Streams do
  @moduledoc false
  # A Foxglove session's subscriptions and the blackboard behind them:
  # the client's subscription ids by channel, the session's blackboard
  # subscriptions (one per tag its subscribed channels read, kept in step),
  # and the messageData frames a tuple makes.
  #
  # Bounded: the blackboard drops tuples for a session whose mailbox holds
  # @max_queue of them (a slow client gets fewer messages, it never slows a
  # writer), and a message over @max_message bytes is not sent (a status
  # warning says so, once per channel).

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Foxglove.{Channels, Messages}

  @max_queue 200
  @max_message 16 * 1024 * 1024

  @doc "The blackboard subscriptions brought in step with the subscribed channels' tags."
  @spec sync_tags(map()) :: map()
  def sync_tags(state) do
    wanted =
      for {_sub, channel_id} <- state.subs,
          channel = state.channels[channel_id],
          channel != nil,
          into: MapSet.new([:robot]),
          do: channel.tag

    have = state.tags |> Map.keys() |> MapSet.new()

    added =
      for tag <- MapSet.difference(wanted, have), into: %{} do
        {:ok, ref} = Blackboard.subscribe({tag, :_, :_}, max_queue: @max_queue)
        {tag, ref}
      end

    removed = MapSet.difference(have, wanted)
    for tag <- removed, do: Blackboard.unsubscribe(state.tags[tag])
    %{state | tags: state.tags |> Map.drop(MapSet.to_list(removed)) |> Map.merge(added)}
  end

  @doc "The frames of the newest tuple behind `channel`, for subscription `sub` alone."
  @spec latest(map(), non_neg_integer(), Channels.channel()) :: {[Messages.frame()], map()}
  def latest(state, sub, channel) do
    case Blackboard.rdp({channel.tag, channel.robot, :_}) do
      {:ok, tuple} ->
        frames(state, tuple, fn channel_id -> if channel_id == channel.id, do: [sub], else: [] end)

      :none ->
        {[], state}
    end
  end

  @doc "The messageData frames of a blackboard tuple, for every subscription it feeds."
  @spec publish(map(), tuple()) :: {[Messages.frame()], map()}
  def publish(state, {tag, robot, _payload} = tuple) do
    if Enum.any?(state.subs, fn {_sub, id} ->
         match?(%{tag: ^tag, robot: ^robot}, state.channels[id])
       end) do
      by_channel = Enum.group_by(state.subs, fn {_sub, id} -> id end, fn {sub, _id} -> sub end)
      frames(state, tuple, &Map.get(by_channel, &1, []))
    else
      {[], state}
    end
  end

  defp frames(state, tuple, subs_of) do
    {time, messages} = Channels.messages(tuple)

    Enum.reduce(messages, {[], state}, fn {topic, schema, json}, {frames, state} ->
      with id when id != nil <- state.by_topic[topic],
           %{schema: ^schema} <- state.channels[id],
           [_ | _] = subs <- subs_of.(id) do
        if IO.iodata_length(json) > @max_message do
          too_big(frames, state, topic)
        else
          {frames ++ Enum.map(subs, &Messages.message_data(&1, time, json)), state}
        end
      else
        _ -> {frames, state}
      end
    end)
  end

  defp too_big(frames, state, topic) do
    if MapSet.member?(state.too_big, topic) do
      {frames, state}
    else
      warning =
        Messages.status(:warning, "#{topic}: a message over #{@max_message} bytes was not sent")

      {frames ++ [warning], %{state | too_big: MapSet.put(state.too_big, topic)}}
    end
  end
end
