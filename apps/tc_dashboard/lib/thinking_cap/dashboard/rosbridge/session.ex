defmodule ThinkingCap.Dashboard.Rosbridge.Session do
  @moduledoc false
  # One rosbridge client: the handler that ThinkingCap.Dashboard.Core.Socket
  # runs for every WebSocket of the rosbridge port (the protocol and the
  # topics are described in ThinkingCap.Dashboard.Rosbridge). It holds the
  # state and passes the client's messages to Rosbridge.Ops, the
  # blackboard's tuples and the throttle's timers to Rosbridge.Subscriptions.
  #
  # State of a session:
  #   * robots - what it knows of the robots (`{:robot, id, caps}` tuples,
  #     read at open and followed), `%{"r1" => %{id: :r1, caps: caps}}`;
  #   * subs - its subscriptions by topic name (Rosbridge.Subscriptions);
  #   * tags - its blackboard subscriptions, one per tag the subscribed
  #     topics read (`:robot` always), kept in step with subs;
  #   * latest - the newest odometry and localizer estimate of each robot,
  #     for `/tf` (Rosbridge.Snapshot);
  #   * adverts - the topics it advertised; driven - the robots it drove
  #     through /cmd_vel (released when it goes, if it still drives them:
  #     Rosbridge.Driving);
  #   * control, token, auth_failures - whether it may publish, the token
  #     the auth op is checked against, the wrong ones so far;
  #   * level - the lowest status level it is sent (Rosbridge.Frames).
  #
  # Nothing a client sends can crash it: every message is checked and a bad
  # one gets a `status` error (the id echoed) and changes nothing.

  @behaviour ThinkingCap.Dashboard.Core.Socket

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Tuples
  require Tuples
  alias ThinkingCap.Dashboard.Rosbridge.{Driving, Frames, Ops, Snapshot, Subscriptions}

  @impl true
  def init(conn) do
    {ip, port} = conn.peer || {nil, nil}

    {:ok,
     %{
       control: conn.control == true,
       token: conn.config[:token],
       world: conn.config[:world],
       by: "rosbridge #{format_ip(ip)}:#{port}",
       level: Frames.level("error"),
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
  def error_frame(message), do: Frames.status_frame("error", message, nil)

  @impl true
  def terminate(_reason, state) do
    for robot <- state.driven, do: Driving.release(robot, state.by)
    for {_tag, ref} <- state.tags, do: Blackboard.unsubscribe(ref)
    :ok
  end

  @impl true
  def handle_text(text, state) do
    case Ops.handle_text(text, state) do
      {:close, state} -> {:close, state}
      {frames, state} -> reply(frames, state)
    end
  end

  @impl true
  def handle_info(:open, state) do
    {:ok, ref} = Blackboard.subscribe(Tuples.robot())

    robots =
      for Tuples.robot(id, caps) when is_atom(id) and is_map(caps) <-
            Blackboard.rd_all(Tuples.robot()),
          into: %{},
          do: {Atom.to_string(id), %{id: id, caps: caps}}

    {:noreply, %{state | robots: robots, tags: %{robot: ref}}}
  end

  def handle_info({:blackboard, _ref, {tag, id, payload}}, state)
      when is_atom(tag) and is_atom(id) and is_map(payload) do
    robot = Atom.to_string(id)

    state =
      if tag == Tuples.tag(:robot) do
        robots = Map.put(state.robots, robot, %{id: id, caps: payload})
        %{state | robots: robots, tags: Subscriptions.sync_tags(state.tags, state.subs, robots)}
      else
        state
      end

    latest = Snapshot.remember(state.latest, state.robots, tag, robot, payload)

    {frames, subs} =
      Subscriptions.publish_tuple(state.subs, {tag, robot, payload}, state.robots, latest, now())

    reply(frames, %{state | latest: latest, subs: subs})
  end

  def handle_info({:rosbridge_flush, name, key}, state) do
    {frames, subs} = Subscriptions.flush(state.subs, name, key, now())
    reply(frames, %{state | subs: subs})
  end

  def handle_info(_message, state), do: {:noreply, state}

  defp reply([], state), do: {:noreply, state}
  defp reply(frames, state), do: {:reply, frames, state}

  defp format_ip(nil), do: "?"
  defp format_ip(ip) when is_tuple(ip), do: ip |> :inet.ntoa() |> to_string()
  defp format_ip(other), do: inspect(other)

  defp now, do: System.monotonic_time(:millisecond)
end
