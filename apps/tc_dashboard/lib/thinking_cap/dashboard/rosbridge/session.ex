defmodule ThinkingCap.Dashboard.Rosbridge.Session do
  @moduledoc false
  # One rosbridge client: the handler that ThinkingCap.Dashboard.Core.Socket
  # runs for every WebSocket of the rosbridge port (the protocol and the
  # topics are described in ThinkingCap.Dashboard.Rosbridge).
  #
  # State of a session:
  #   * robots - what it knows of the robots (`{:robot, id, caps}` tuples,
  #     read at open and followed), `%{"r1" => %{id: :r1, caps: caps}}`;
  #   * subs - its subscriptions by topic name: the topic, the client's
  #     subscription ids with their throttle rates (the smallest one
  #     applies), and per stream (a robot, or nil) the time of the last
  #     message sent, the newest message held back by the throttle and the
  #     timer that will send it;
  #   * tags - its blackboard subscriptions, one per tag the subscribed
  #     topics read (`:robot` always), kept in step with subs by sync_tags/1;
  #   * latest - the newest odometry and localizer estimate of each robot,
  #     for `/tf`;
  #   * adverts - the topics it advertised; driven - the robots it drove
  #     through /cmd_vel (released when it goes, if it still drives them).
  #
  # Nothing a client sends can crash it: every message is checked and a bad
  # one gets a `status` error (the id echoed) and changes nothing.

  @behaviour ThinkingCap.Dashboard.Core.Socket

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Control
  alias ThinkingCap.Dashboard.Core.{Access, JSON}
  alias ThinkingCap.Dashboard.Rosbridge.{Messages, Services, Topics, WorldMap}
  alias ThinkingCap.Navigation.OccupancyGrid

  @levels %{"info" => 0, "warning" => 1, "error" => 2, "none" => 3}
  @max_ids 256
  @max_throttle 3_600_000
  @max_auth_failures 5
  @unsupported ~w(fragment png advertise_service unadvertise_service send_action_goal
                  cancel_action_goal advertise_action unadvertise_action action_feedback
                  action_result)

  @impl true
  def init(conn) do
    {ip, port} = conn.peer || {nil, nil}

    {:ok,
     %{
       control: conn.control == true,
       token: conn.config[:token],
       world: conn.config[:world],
       by: "rosbridge #{format_ip(ip)}:#{port}",
       level: @levels["error"],
       robots: %{},
       subs: %{},
       tags: %{},
       latest: %{},
       adverts: %{},
       driven: MapSet.new(),
       auth_failures: 0
     }}
  end

  @impl true
  def error_frame(message), do: status_frame("error", message, nil)

  @impl true
  def terminate(_reason, state) do
    for robot <- state.driven, do: release(robot, state)
    for {_tag, ref} <- state.tags, do: Blackboard.unsubscribe(ref)
    :ok
  end

  ## blackboard and timers

  @impl true
  def handle_info(:open, state) do
    {:ok, ref} = Blackboard.subscribe({:robot, :_, :_})

    robots =
      for {:robot, id, caps} when is_atom(id) and is_map(caps) <-
            Blackboard.rd_all({:robot, :_, :_}),
          into: %{},
          do: {Atom.to_string(id), %{id: id, caps: caps}}

    {:noreply, %{state | robots: robots, tags: %{robot: ref}}}
  end

  def handle_info({:blackboard, _ref, {tag, id, payload}}, state)
      when is_atom(tag) and is_atom(id) and is_map(payload) do
    robot = Atom.to_string(id)

    state =
      if tag == :robot,
        do: sync_tags(%{state | robots: Map.put(state.robots, robot, %{id: id, caps: payload})}),
        else: state

    state = remember(state, tag, robot, payload)
    now = now()

    {frames, state} =
      Enum.reduce(state.subs, {[], state}, fn {name, sub}, {frames, state} ->
        if Topics.feeds?(sub.topic, tag, robot, state.robots) do
          sub.topic
          |> messages(tag, robot, payload, state)
          |> offer_all(name, now, {frames, state})
        else
          {frames, state}
        end
      end)

    reply(frames, state)
  end

  def handle_info({:rosbridge_flush, name, key}, state) do
    with %{pending: %{^key => msg}} = sub <- state.subs[name] do
      sub = %{
        sub
        | pending: Map.delete(sub.pending, key),
          timers: Map.delete(sub.timers, key),
          last: Map.put(sub.last, key, now())
      }

      {:reply, [publish_frame(name, msg)], put_in(state.subs[name], sub)}
    else
      _ -> {:noreply, state}
    end
  end

  def handle_info(_message, state), do: {:noreply, state}

  defp remember(state, :pose, robot, payload),
    do: %{state | latest: Map.put(state.latest, {robot, :pose}, payload)}

  defp remember(state, tag, robot, payload) do
    if tag == Topics.sensor_tag(state.robots, robot, :odometry, :odom),
      do: %{state | latest: Map.put(state.latest, {robot, :odom}, payload)},
      else: state
  end

  ## client messages

  @impl true
  def handle_text(text, state) do
    case JSON.decode(text) do
      {:ok, %{} = message} ->
        id = id_of(message)

        case handle(message["op"], message, id, state) do
          {:close, state} -> {:close, state}
          {frames, state} -> reply(frames, state)
        end

      {:ok, other} ->
        reply(
          status(
            state,
            "error",
            "a rosbridge message is a JSON object, not #{short(other)}",
            nil
          ),
          state
        )

      {:error, reason} ->
        reply(status(state, "error", reason, nil), state)
    end
  end

  defp handle("subscribe", m, id, state) do
    with {:ok, topic} <- Topics.resolve(m["topic"], state.robots),
         :ok <- check_type(topic, m["type"]),
         {:ok, throttle} <- throttle(m["throttle_rate"]),
         :ok <- check_room(state, id, topic.name),
         {:ok, initial, state} <- initial(topic, state) do
      warnings = compression_warning(state, m["compression"], id)

      sub =
        Map.get(state.subs, topic.name, %{
          topic: topic,
          ids: %{},
          last: %{},
          pending: %{},
          timers: %{}
        })

      state =
        sync_tags(put_in(state.subs[topic.name], %{sub | ids: Map.put(sub.ids, id, throttle)}))

      {frames, state} = offer_all(initial, topic.name, now(), {[], state})
      {warnings ++ frames, state}
    else
      {:error, reason} -> {status(state, "error", "subscribe: #{reason}", id), state}
    end
  end

  defp handle("unsubscribe", m, id, state) do
    name = if is_binary(m["topic"]), do: Topics.absolute(m["topic"])

    case state.subs[name] do
      nil ->
        {status(state, "warning", "unsubscribe: not subscribed to #{short(m["topic"])}", id),
         state}

      # without an id, every subscription to the topic goes
      sub when id == nil or is_map_key(sub.ids, id) ->
        ids = if id == nil, do: %{}, else: Map.delete(sub.ids, id)

        state =
          if ids == %{} do
            for {_key, ref} <- sub.timers, do: Process.cancel_timer(ref)
            sync_tags(%{state | subs: Map.delete(state.subs, name)})
          else
            put_in(state.subs[name].ids, ids)
          end

        {[], state}

      _sub ->
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
          {:ok, %{kind: :cmd_vel, robot: robot}} -> {[], stop_driving(robot, state)}
          _ -> {[], state}
        end
    end
  end

  defp handle("publish", m, id, state) do
    with {:ok, topic} <- Topics.resolve(m["topic"], state.robots),
         :ok <- check_publishable(topic),
         :ok <- check_control(state, topic),
         {:ok, robot} <- robot_id(topic.robot, state),
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
        map? = state.world != nil or Blackboard.rdp({:map, :_, :_}) != :none
        topics = Topics.list(state.robots, map?)

        response =
          case Services.call(service, m["args"], topics) do
            {:ok, values} ->
              %{op: "service_response", service: service, values: values, result: true}

            {:error, reason} ->
              %{op: "service_response", service: service, values: reason, result: false}
          end

        {[JSON.encode!(with_id(response, id))], state}

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
    case @levels[m["level"]] do
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
      Enum.reduce(state.subs, 0, fn {_, sub}, n -> n + map_size(sub.ids) end) +
        Enum.reduce(state.adverts, 0, fn {_, ids}, n -> n + MapSet.size(ids) end)

    already? =
      match?(%{ids: %{^id => _}}, state.subs[name]) or
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

  defp robot_id(name, state) do
    case state.robots[name] do
      %{id: id} -> {:ok, id}
      nil -> Control.robot(name)
    end
  end

  ## messages of the topics

  # what a subscription sends at once: the topics' latest values
  defp initial(%{kind: :map, robot: only} = topic, state) do
    # a request that has no map to send (or only an error) costs nothing
    nothing = state.world == nil and Blackboard.rdp({:map, :_, :_}) == :none

    if nothing or WorldMap.allow_send?(),
      do: initial_map(topic, only, state),
      else: {:error, "too many map requests on this node just now: try again in a second"}
  end

  defp initial(%{kind: :tf, robot: only} = topic, state) do
    state = prime_latest(topic, state)

    messages =
      for {name, _info} <- state.robots,
          only == nil or only == name,
          transforms = tf(name, state),
          transforms != [],
          do: {name, Messages.tf_message(transforms)}

    {:ok, messages, state}
  end

  defp initial(%{kind: :tf_static, robot: only}, state) do
    messages =
      for {name, %{caps: caps}} <- state.robots,
          only == nil or only == name,
          transforms = Messages.static_transforms(name, caps),
          transforms != [],
          do: {name, Messages.tf_message(transforms)}

    {:ok, messages, state}
  end

  defp initial(topic, state) do
    messages =
      for tag <- Topics.tags(topic, state.robots),
          {^tag, id, payload} when is_atom(id) and is_map(payload) <-
            Blackboard.rd_all({tag, :_, :_}),
          robot = Atom.to_string(id),
          Topics.feeds?(topic, tag, robot, state.robots),
          message <- messages(topic, tag, robot, payload, state),
          do: message

    {:ok, messages, state}
  end

  # the map a robot learned (ThinkingCap.Navigation.Mapper), else the world's
  defp initial_map(topic, only, state) do
    learned =
      for {:map, id, %OccupancyGrid{} = map} <- Blackboard.rd_all({:map, :_, :_}),
          robot = to_string(id),
          only == nil or only == robot,
          message <- messages(topic, :map, robot, map, state),
          do: message

    case {learned, only} do
      {[_ | _], _} ->
        {:ok, learned, state}

      {[], nil} ->
        case WorldMap.cells(state.world) do
          {:ok, cells} -> {:ok, [{nil, Messages.occupancy_grid(cells)}], state}
          {:error, reason} -> {:error, reason}
        end

      {[], _robot} ->
        {:ok, [], state}
    end
  end

  defp prime_latest(topic, state) do
    Enum.reduce(Topics.tags(topic, state.robots), state, fn tag, state ->
      Enum.reduce(Blackboard.rd_all({tag, :_, :_}), state, fn
        {^tag, id, payload}, state when is_atom(id) and is_map(payload) ->
          remember(state, tag, Atom.to_string(id), payload)

        _, state ->
          state
      end)
    end)
  end

  # the messages a tuple makes on a topic it feeds, each {stream key, msg}
  defp messages(%{kind: :scan}, tag, robot, payload, _state),
    do: [{robot, Messages.laser_scan(payload, Messages.frame(robot, tag))}]

  defp messages(%{kind: :odom}, _tag, robot, payload, _state),
    do: [{robot, Messages.odometry(payload, robot)}]

  defp messages(%{kind: :pose}, _tag, robot, payload, _state),
    do: [{robot, Messages.pose_with_covariance(payload)}]

  defp messages(%{kind: :cmd_vel}, _tag, robot, payload, _state) do
    case payload[:command] do
      {:velocity, v, w} when is_number(v) and is_number(w) -> [{robot, Messages.twist(v, w)}]
      :stop -> [{robot, Messages.twist(0, 0)}]
      _other -> []
    end
  end

  defp messages(%{kind: :tf}, _tag, robot, _payload, state) do
    case tf(robot, state) do
      [] -> []
      transforms -> [{robot, Messages.tf_message(transforms)}]
    end
  end

  defp messages(%{kind: :tf_static}, _tag, robot, caps, _state) do
    case Messages.static_transforms(robot, caps) do
      [] -> []
      transforms -> [{robot, Messages.tf_message(transforms)}]
    end
  end

  defp messages(%{kind: :map}, :map, robot, %OccupancyGrid{origin: {x, y}} = map, _state),
    do: [{robot, Messages.occupancy_grid(%{map | origin: {x, y, 0.0}})}]

  defp messages(_topic, _tag, _robot, _payload, _state), do: []

  defp tf(robot, state),
    do:
      Messages.robot_transforms(
        robot,
        state.latest[{robot, :odom}],
        state.latest[{robot, :pose}]
      )

  ## throttling

  # sends `messages` on topic `name` now, or holds each back (the newest per
  # stream) until its stream's throttle period has passed
  defp offer_all(messages, name, now, acc) do
    Enum.reduce(messages, acc, fn {key, msg}, {frames, state} ->
      sub = state.subs[name]
      throttle = sub.ids |> Map.values() |> Enum.min(fn -> 0 end)
      last = sub.last[key]

      cond do
        throttle == 0 or last == nil or now - last >= throttle ->
          sub = %{sub | last: Map.put(sub.last, key, now), pending: Map.delete(sub.pending, key)}
          sub = cancel_timer(sub, key)
          {frames ++ [publish_frame(name, msg)], put_in(state.subs[name], sub)}

        Map.has_key?(sub.timers, key) ->
          {frames, put_in(state.subs[name].pending[key], msg)}

        true ->
          ref = Process.send_after(self(), {:rosbridge_flush, name, key}, throttle - (now - last))

          sub = %{
            sub
            | pending: Map.put(sub.pending, key, msg),
              timers: Map.put(sub.timers, key, ref)
          }

          {frames, put_in(state.subs[name], sub)}
      end
    end)
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

  ## blackboard subscriptions

  # one blackboard subscription per tag the subscribed topics read
  defp sync_tags(state) do
    wanted =
      for {_name, sub} <- state.subs,
          tag <- Topics.tags(sub.topic, state.robots),
          into: MapSet.new([:robot]),
          do: tag

    have = state.tags |> Map.keys() |> MapSet.new()

    added =
      for tag <- MapSet.difference(wanted, have), into: %{} do
        {:ok, ref} = Blackboard.subscribe({tag, :_, :_})
        {tag, ref}
      end

    removed = MapSet.difference(have, wanted)
    for tag <- removed, do: Blackboard.unsubscribe(state.tags[tag])
    %{state | tags: state.tags |> Map.drop(MapSet.to_list(removed)) |> Map.merge(added)}
  end

  ## driving

  defp stop_driving(robot_name, state) do
    case Enum.find(state.driven, &(Atom.to_string(&1) == robot_name)) do
      nil ->
        state

      robot ->
        release(robot, state)
        %{state | driven: MapSet.delete(state.driven, robot)}
    end
  end

  # hands the robot back, unless someone else has taken it meanwhile
  defp release(robot, state) do
    case Blackboard.rdp({:teleop, robot, :_}) do
      {:ok, {:teleop, ^robot, %{by: by, command: {:velocity, _, _}}}} when by == state.by ->
        Control.teleop_release(robot, state.by)

      _ ->
        :ok
    end
  end

  ## replies

  defp reply([], state), do: {:noreply, state}
  defp reply(frames, state), do: {:reply, frames, state}

  defp publish_frame(name, msg), do: JSON.encode!(%{op: "publish", topic: name, msg: msg})

  defp status(state, level, message, id) do
    if @levels[level] >= state.level, do: [status_frame(level, message, id)], else: []
  end

  defp status_frame(level, message, id),
    do: JSON.encode!(with_id(%{op: "status", level: level, msg: message}, id))

  defp with_id(map, nil), do: map
  defp with_id(map, id), do: Map.put(map, :id, id)

  defp id_of(%{"id" => id}) when is_binary(id) and byte_size(id) <= 256, do: id
  defp id_of(%{"id" => id}) when is_integer(id) and abs(id) < 1_000_000_000_000_000_000, do: id
  defp id_of(_), do: nil

  defp short(term), do: inspect(term, limit: 5, printable_limit: 60)

  defp format_ip(nil), do: "?"
  defp format_ip(ip) when is_tuple(ip), do: ip |> :inet.ntoa() |> to_string()
  defp format_ip(other), do: inspect(other)

  defp now, do: System.monotonic_time(:millisecond)
end
