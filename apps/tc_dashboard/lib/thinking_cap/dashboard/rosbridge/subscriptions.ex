defmodule ThinkingCap.Dashboard.Rosbridge.Subscriptions do
  @moduledoc false
  # A rosbridge session's subscriptions, by topic name: the topic, the
  # client's subscription ids with their throttle rates (the smallest one
  # applies), and per stream (a robot, or nil) the time of the last message
  # sent, the newest message held back by the throttle and the timer that
  # will send it (`{:rosbridge_flush, name, key}` to the session). Also the
  # session's blackboard subscriptions, one per tag the topics read.

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Rosbridge.{Frames, Messages, Topics}

  @type sub :: %{
          topic: Topics.topic(),
          ids: %{term() => non_neg_integer()},
          last: %{term() => integer()},
          pending: %{term() => map()},
          timers: %{term() => reference()}
        }
  @type subs :: %{String.t() => sub()}

  @doc "Adds the client's subscription `id` to `topic`, with its throttle rate in ms."
  @spec add(subs(), Topics.topic(), term(), non_neg_integer()) :: subs()
  def add(subs, topic, id, throttle) do
    sub =
      Map.get(subs, topic.name, %{topic: topic, ids: %{}, last: %{}, pending: %{}, timers: %{}})

    Map.put(subs, topic.name, %{sub | ids: Map.put(sub.ids, id, throttle)})
  end

  @doc """
  Removes the subscription `id` to topic `name` (nil: every subscription
  to it); the topic goes with its last id, its timers cancelled.
  """
  @spec remove(subs(), String.t(), term()) ::
          {:ok, subs()} | {:error, :not_subscribed | :unknown_id}
  def remove(subs, name, id) do
    case subs[name] do
      nil ->
        {:error, :not_subscribed}

      sub when id == nil or is_map_key(sub.ids, id) ->
        ids = if id == nil, do: %{}, else: Map.delete(sub.ids, id)

        if ids == %{} do
          for {_key, ref} <- sub.timers, do: Process.cancel_timer(ref)
          {:ok, Map.delete(subs, name)}
        else
          {:ok, put_in(subs[name].ids, ids)}
        end

      _sub ->
        {:error, :unknown_id}
    end
  end

  @doc "The number of subscription ids over every topic."
  @spec count(subs()) :: non_neg_integer()
  def count(subs), do: Enum.reduce(subs, 0, fn {_, sub}, n -> n + map_size(sub.ids) end)

  @doc "Whether the client has a subscription `id` to topic `name`."
  @spec subscribed?(subs(), String.t(), term()) :: boolean()
  def subscribed?(subs, name, id), do: match?(%{ids: %{^id => _}}, subs[name])

  @doc """
  The `publish` frames a blackboard tuple makes on the topics it feeds
  (`latest` as `Messages.of_tuple/5` takes it), throttled.
  """
  @spec publish_tuple(subs(), {atom(), String.t(), term()}, Topics.robots(), map(), integer()) ::
          {[iodata()], subs()}
  def publish_tuple(subs, {tag, robot, payload}, robots, latest, now) do
    Enum.reduce(subs, {[], subs}, fn {name, sub}, acc ->
      if Topics.feeds?(sub.topic, tag, robot, robots) do
        sub.topic
        |> Messages.of_tuple(tag, robot, payload, latest)
        |> offer(name, now, acc)
      else
        acc
      end
    end)
  end

  @doc """
  Adds to `{frames, subs}` the `publish` frames of `messages` (each
  `{stream key, msg}`) on topic `name`, sent now, or each held back (the
  newest per stream) until its stream's throttle period has passed.
  """
  @spec offer([{term(), map()}], String.t(), integer(), {[iodata()], subs()}) ::
          {[iodata()], subs()}
  def offer(messages, name, now, acc) do
    Enum.reduce(messages, acc, fn {key, msg}, {frames, subs} ->
      sub = subs[name]
      throttle = sub.ids |> Map.values() |> Enum.min(fn -> 0 end)
      last = sub.last[key]

      cond do
        throttle == 0 or last == nil or now - last >= throttle ->
          sub = %{sub | last: Map.put(sub.last, key, now), pending: Map.delete(sub.pending, key)}
          sub = cancel_timer(sub, key)
          {frames ++ [Frames.publish(name, msg)], Map.put(subs, name, sub)}

        Map.has_key?(sub.timers, key) ->
          {frames, put_in(subs[name].pending[key], msg)}

        true ->
          ref = Process.send_after(self(), {:rosbridge_flush, name, key}, throttle - (now - last))

          sub = %{
            sub
            | pending: Map.put(sub.pending, key, msg),
              timers: Map.put(sub.timers, key, ref)
          }

          {frames, Map.put(subs, name, sub)}
      end
    end)
  end

  @doc "The frame of the message held back on stream `key` of topic `name`, its timer fired."
  @spec flush(subs(), String.t(), term(), integer()) :: {[iodata()], subs()}
  def flush(subs, name, key, now) do
    with %{pending: %{^key => msg}} = sub <- subs[name] do
      sub = %{
        sub
        | pending: Map.delete(sub.pending, key),
          timers: Map.delete(sub.timers, key),
          last: Map.put(sub.last, key, now)
      }

      {[Frames.publish(name, msg)], Map.put(subs, name, sub)}
    else
      _ -> {[], subs}
    end
  end

  defp cancel_timer(sub, key) do
    case Map.pop(sub.timers, key) do
      {nil, _} ->
        sub

      {ref, timers} ->
        Process.cancel_timer(ref)
        %{sub | timers: timers}
    end
  end

  @doc """
  The session's blackboard subscriptions (`tags`, a ref per tag) brought
  in step with the tags its topics read (`:robot` always).
  """
  @spec sync_tags(%{atom() => reference()}, subs(), Topics.robots()) :: %{atom() => reference()}
  def sync_tags(tags, subs, robots) do
    wanted =
      for {_name, sub} <- subs,
          tag <- Topics.tags(sub.topic, robots),
          into: MapSet.new([:robot]),
          do: tag

    have = tags |> Map.keys() |> MapSet.new()

    added =
      for tag <- MapSet.difference(wanted, have), into: %{} do
        {:ok, ref} = Blackboard.subscribe({tag, :_, :_})
        {tag, ref}
      end

    removed = MapSet.difference(have, wanted)
    for tag <- removed, do: Blackboard.unsubscribe(tags[tag])
    tags |> Map.drop(MapSet.to_list(removed)) |> Map.merge(added)
  end
end
