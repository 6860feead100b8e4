defmodule ThinkingCap.Dashboard.Rosbridge.Ops do
  @moduledoc false
  # The rosbridge v2 operations a client sends, each checked and turned
  # into a change of the session's state and the frames to send back (the
  # session's state is described in ThinkingCap.Dashboard.Rosbridge.Session).
  # A bad message gets a `status` error (the id echoed) and changes nothing.

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Tuples
  require Tuples
  alias ThinkingCap.Dashboard.Control
  alias ThinkingCap.Dashboard.Core.{Access, JSON}

  alias ThinkingCap.Dashboard.Rosbridge.{
    Driving,
    Frames,
    Messages,
    Services,
    Snapshot,
    Subscriptions,
    Topics
  }

  import Frames, only: [short: 1]

  @max_ids 256
  @max_throttle 3_600_000
  @max_auth_failures 5
  @unsupported ~w(fragment png advertise_service unadvertise_service send_action_goal
                  cancel_action_goal advertise_action unadvertise_action action_feedback
                  action_result)

  @doc "Handles a client's text frame: the frames to send and the new state, or `:close`."
  @spec handle_text(binary(), map()) :: {[iodata()], map()} | {:close, map()}
  def handle_text(text, state) do
    case JSON.decode(text) do
      {:ok, %{} = message} ->
        handle(message["op"], message, Frames.id_of(message), state)

      {:ok, other} ->
        {status(state, "error", "a rosbridge message is a JSON object, not #{short(other)}", nil),
         state}

      {:error, reason} ->
        {status(state, "error", reason, nil), state}
    end
  end

  defp handle("subscribe", m, id, state) do
    with {:ok, topic} <- Topics.resolve(m["topic"], state.robots),
         :ok <- check_type(topic, m["type"]),
         {:ok, throttle} <- throttle(m["throttle_rate"]),
         :ok <- check_room(state, id, topic.name),
         {:ok, initial, latest} <-
           Snapshot.initial(topic, state.robots, state.world, state.latest) do
      warnings = compression_warning(state, m["compression"], id)
      subs = Subscriptions.add(state.subs, topic, id, throttle)
      state = sync_tags(%{state | subs: subs, latest: latest})
      {frames, subs} = Subscriptions.offer(initial, topic.name, now(), {[], state.subs})
      {warnings ++ frames, %{state | subs: subs}}
    else
      {:error, reason} -> {status(state, "error", "subscribe: #{reason}", id), state}
    end
  end

  defp handle("unsubscribe", m, id, state) do
    name = if is_binary(m["topic"]), do: Topics.absolute(m["topic"])

    # without an id, every subscription to the topic goes
    case Subscriptions.remove(state.subs, name, id) do
      {:ok, subs} ->
        {[], sync_tags(%{state | subs: subs})}

      {:error, :not_subscribed} ->
        {status(state, "warning", "unsubscribe: not subscribed to #{short(m["topic"])}", id),
         state}

      {:error, :unknown_id} ->
        {status(state, "warning", "unsubscribe: no subscription #{short(id)} to #{name}", id),
         state}
    end
  end

  defp handle("advertise", m, id, state) do
    with {:ok, topic} <- Topics.resolve(m["topic"], state.robots),
         :ok <- check_publishable(topic),
         :ok <- if(is_binary(m["type"]), do: :ok, else: {:error, "a type is required"}),
         :ok <- check_type(topic, m["type"]),
         :ok <- check_room(state, id, topic.name) do
      ids = state.adverts |> Map.get(topic.name, MapSet.new()) |> MapSet.put(id)
      state = put_in(state.adverts[topic.name], ids)

      if state.control,
        do: {[], state},
        else:
          {status(
             state,
             "warning",
             "advertise: publishing #{topic.name} needs the access token (?token= in the URL, or the auth op)",
             id
           ), state}
    else
      {:error, reason} -> {status(state, "error", "advertise: #{reason}", id), state}
    end
  end

  defp handle("unadvertise", m, id, state) do
    name = if is_binary(m["topic"]), do: Topics.absolute(m["topic"])

    case state.adverts[name] do
      nil ->
        {status(state, "warning", "unadvertise: #{short(m["topic"])} is not advertised", id),
         state}

      _ids ->
        state = %{state | adverts: Map.delete(state.adverts, name)}

        case Topics.resolve(name, state.robots) do
          {:ok, %{kind: :cmd_vel, robot: robot}} ->
            {[], %{state | driven: Driving.stop(state.driven, robot, state.by)}}

          _ ->
            {[], state}
        end
    end
  end

  defp handle("publish", m, id, state) do
    with {:ok, topic} <- Topics.resolve(m["topic"], state.robots),
         :ok <- check_publishable(topic),
         :ok <- check_control(state, topic),
         {:ok, robot} <- Driving.robot_id(topic.robot, state.robots),
         {:ok, {v, w}} <- Messages.from_twist(m["msg"]),
         {:ok, _clamped} <- Control.teleop(robot, v, w, by: state.by) do
      {[], %{state | driven: MapSet.put(state.driven, robot)}}
    else
      {:error, reason} -> {status(state, "error", "publish: #{reason}", id), state}
    end
  end

  defp handle("call_service", m, id, state) do
    case m["service"] do
      service when is_binary(service) and byte_size(service) <= 256 ->
        service = Topics.absolute(service)
        # /map when there is a world, or a map a robot learned
        map? = state.world != nil or Blackboard.rdp(Tuples.map()) != :none
        topics = Topics.list(state.robots, map?)

        response =
          case Services.call(service, m["args"], topics) do
            {:ok, values} ->
              %{op: "service_response", service: service, values: values, result: true}

            {:error, reason} ->
              %{op: "service_response", service: service, values: reason, result: false}
          end

        {[JSON.encode!(Frames.with_id(response, id))], state}

      other ->
        {status(
           state,
           "error",
           "call_service: a service name is required, not #{short(other)}",
           id
         ), state}
    end
  end

  defp handle("service_response", _m, id, state),
    do:
      {status(
         state,
         "error",
         "service_response: this server calls no client services (advertise_service is not supported)",
         id
       ), state}

  defp handle("set_level", m, id, state) do
    case Frames.level(m["level"]) do
      nil ->
        {status(state, "error", "set_level: level is one of info, warning, error, none", id),
         state}

      level ->
        {[], %{state | level: level}}
    end
  end

  defp handle("auth", m, id, state) do
    if Access.valid_token?(m["mac"], state.token) do
      state = %{state | control: true, auth_failures: 0}
      {status(state, "info", "auth: authenticated; publishing /cmd_vel is allowed", id), state}
    else
      state = %{state | auth_failures: state.auth_failures + 1}

      if state.auth_failures >= @max_auth_failures,
        do: {:close, state},
        else: {status(state, "error", "auth: the mac is not the access token", id), state}
    end
  end

  defp handle("status", _m, id, state),
    do: {status(state, "error", "status messages are sent by the server", id), state}

  defp handle(op, _m, id, state) when op in @unsupported,
    do: {status(state, "error", "op #{op} is not supported by this server", id), state}

  defp handle(nil, _m, id, state),
    do: {status(state, "error", "a rosbridge message needs an op", id), state}

  defp handle(op, _m, id, state),
    do: {status(state, "error", "unknown op #{short(op)}", id), state}

  ## checks

  defp check_type(topic, type) do
    if Topics.type_matches?(topic, type),
      do: :ok,
      else: {:error, "#{topic.name} is a #{topic.type}, not #{short(type)}"}
  end

  defp check_publishable(%{kind: :cmd_vel}), do: :ok

  defp check_publishable(topic),
    do: {:error, "#{topic.name} is published by this server; clients may publish only cmd_vel"}

  defp check_control(%{control: true}, _topic), do: :ok

  defp check_control(_state, topic),
    do:
      {:error,
       "publishing #{topic.name} needs the access token (?token= in the URL, or the auth op)"}

  defp throttle(nil), do: {:ok, 0}

  defp throttle(ms) when is_number(ms) and ms >= 0,
    do: {:ok, ms |> min(@max_throttle) |> trunc()}

  defp throttle(other),
    do: {:error, "throttle_rate must be a non-negative number of ms, not #{short(other)}"}

  defp check_room(state, id, name) do
    count =
      Subscriptions.count(state.subs) +
        Enum.reduce(state.adverts, 0, fn {_, ids}, n -> n + MapSet.size(ids) end)

    already? =
      Subscriptions.subscribed?(state.subs, name, id) or
        MapSet.member?(Map.get(state.adverts, name, MapSet.new()), id)

    if count < @max_ids or already?,
      do: :ok,
      else: {:error, "too many subscriptions and advertisements (#{@max_ids} at most)"}
  end

  defp compression_warning(_state, c, _id) when c in [nil, "none"], do: []

  defp compression_warning(state, c, id),
    do:
      status(
        state,
        "warning",
        "subscribe: compression #{short(c)} is not supported; messages are sent as JSON text",
        id
      )

  defp sync_tags(state),
    do: %{state | tags: Subscriptions.sync_tags(state.tags, state.subs, state.robots)}

  defp status(state, level, message, id), do: Frames.status(state.level, level, message, id)

  defp now, do: System.monotonic_time(:millisecond)
end
