defmodule ThinkingCap.Dashboard.Session do
  @moduledoc """
  One browser's WebSocket session (`/ws`): the server side of the page's
  protocol, written down in `apps/tc_dashboard/PROTOCOL.md`.

  After a `welcome` (its rights, the robots, the world), it sends
  `telemetry` frames of what changed since the browser's last frame, at most
  `telemetry_hz` a second: the next frame is scheduled only once the last
  one was written to the socket, and one that stops reading is dropped by
  the socket's send timeout. A client that acknowledges frames (`ack`, as
  the page does) has at most five of them unacknowledged: a slow browser
  then gets fewer frames, each with the latest values, instead of a queue
  in the socket's buffers that shows it the robots seconds late (five
  frames are 200 ms at 25 a second, about what a busy browser takes to
  answer). Commands from the page become blackboard writes through
  `ThinkingCap.Dashboard.Control`; controlling ones need the access token.
  Every bad message gets an `error` reply and changes nothing.
  """
  @behaviour ThinkingCap.Dashboard.Core.Socket

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.{Control, Dumps, Telemetry, Timeline}
  alias ThinkingCap.Dashboard.Core.JSON
  alias ThinkingCap.Tuples
  require Tuples

  @tail_rate 20
  @max_tails 8
  # telemetry frames a client that acknowledges may have unacknowledged
  @ack_window 5

  @impl true
  def init(conn) do
    {peer_ip, peer_port} = conn.peer || {nil, nil}

    {:ok,
     %{
       control: conn.control,
       by: "page #{format_ip(peer_ip)}:#{peer_port}",
       interval: max(div(1000, conn.config.telemetry_hz), 1),
       version: 0,
       # telemetry frames sent, and the last one acknowledged (nil until the
       # client acknowledges one: then the window applies)
       seq: 0,
       acked: nil,
       tails: %{},
       # the black-box timeline this page scrubs: %{pid, robot}, or nil
       timeline: nil
     }}
  end

  @impl true
  def handle_info(:open, state) do
    send(self(), :tick)

    welcome = [
      ~s({"op":"welcome","version":1,"control":),
      to_string(state.control),
      ~s(,"robots":),
      JSON.encode!(Control.robots()),
      ~s(,"world":),
      Telemetry.world_json(),
      "}"
    ]

    {:reply, [welcome], state}
  end

  def handle_info(:tick, state) do
    Process.send_after(self(), :tick, state.interval)
    if window_open?(state), do: telemetry_frame(state), else: {:noreply, state}
  end

  def handle_info({:blackboard, ref, tuple}, state) do
    case Enum.find(state.tails, fn {_id, tail} -> tail.ref == ref end) do
      nil ->
        {:noreply, state}

      {id, tail} ->
        now = System.monotonic_time(:millisecond)

        {window, count} =
          if now - tail.window >= 1000, do: {now, 0}, else: {tail.window, tail.count}

        if count < @tail_rate do
          tails = Map.put(state.tails, id, %{tail | window: window, count: count + 1})
          {:reply, [encode(%{op: :tuple, id: id, tuple: tuple})], %{state | tails: tails}}
        else
          {:noreply,
           %{state | tails: Map.put(state.tails, id, %{tail | window: window, count: count})}}
        end
    end
  end

  def handle_info(_message, state), do: {:noreply, state}

  @impl true
  def handle_text(text, state) do
    with {:ok, message} <- JSON.decode(text),
         {:ok, message} <- object(message),
         {:ok, reply, state} <- handle(message["op"], message, state) do
      # one reply is one frame, whatever the iodata's shape (jiffy returns
      # a list for a long text: wrapping it made a frame of each piece)
      {:reply, if(reply == :none, do: [], else: [reply]), state}
    else
      {:error, reason} -> {:reply, [error(id_of(text), reason)], state}
      {:error, id, reason} -> {:reply, [error(id, reason)], state}
    end
  end

  defp window_open?(%{acked: nil}), do: true
  defp window_open?(state), do: state.seq - state.acked < @ack_window

  defp telemetry_frame(state) do
    case Telemetry.changes_since(state.version) do
      {_version, []} ->
        {:noreply, state}

      {version, items} ->
        seq = state.seq + 1

        frame = [
          ~s({"op":"telemetry","seq":),
          Integer.to_string(seq),
          ~s(,"t":),
          Integer.to_string(System.os_time(:millisecond)),
          ~s(,"items":{),
          items
          |> Enum.map(fn {key, json} -> [JSON.encode!(key), ?:, json] end)
          |> Enum.intersperse(?,),
          "}}"
        ]

        {:reply, [frame], %{state | version: version, seq: seq}}
    end
  end

  @impl true
  def error_frame(message), do: error(nil, message)

  @impl true
  def terminate(_reason, _state), do: :ok

  ## the ops

  defp handle("ping", m, state), do: {:ok, encode(%{op: :pong, id: m["id"]}), state}

  defp handle("ack", %{"seq" => seq}, state) when is_integer(seq) and seq > 0 do
    if seq <= state.seq,
      do: {:ok, :none, %{state | acked: max(seq, state.acked || 0)}},
      else: {:error, "ack of telemetry frame #{seq}, but #{state.seq} were sent"}
  end

  defp handle("ack", _m, _state),
    do: {:error, "ack needs \"seq\": the positive integer of a telemetry frame"}

  defp handle("teleop", m, state) do
    with :ok <- may_control(m, state),
         {:ok, robot} <- robot(m),
         {:ok, v} <- number(m, "v", 100),
         {:ok, w} <- number(m, "w", 100),
         {:ok, _} <- wrap(m, Control.teleop(robot, v, w, by: state.by, sent_at: m["sent_at"])) do
      {:ok, ok(m), state}
    end
  end

  defp handle("teleop_release", m, state) do
    with :ok <- may_control(m, state), {:ok, robot} <- robot(m) do
      Control.teleop_release(robot, state.by)
      {:ok, ok(m), state}
    end
  end

  # anyone who sees the robot may stop it
  defp handle("estop", m, state) do
    with {:ok, robot} <- robot(m) do
      Control.estop(robot, state.by)
      {:ok, ok(m), state}
    end
  end

  defp handle("estop_release", m, state) do
    with :ok <- may_control(m, state), {:ok, robot} <- robot(m) do
      Control.estop_release(robot, state.by)
      {:ok, ok(m), state}
    end
  end

  defp handle("goal", m, state) do
    with :ok <- may_control(m, state), {:ok, robot} <- robot(m), {:ok, target} <- target(m) do
      Control.goal(robot, target)
      {:ok, ok(m), state}
    end
  end

  defp handle("restart", m, state) do
    with :ok <- may_control(m, state),
         {:ok, name} <- string(m, "module"),
         {:ok, robot} <- if(Map.has_key?(m, "robot"), do: string(m, "robot"), else: {:ok, nil}),
         :ok <- wrap(m, Control.restart(name, robot)) do
      {:ok, ok(m), state}
    end
  end

  # a robot's modules' params, with their schemas (anyone who sees the robot)
  defp handle("params", m, state) do
    with {:ok, robot} <- robot(m) do
      modules =
        for info <- Control.params(robot),
            do: %{name: info.name, module: info.module, live: info.live, fields: info.fields}

      {:ok, encode(%{op: :params, id: m["id"], robot: robot, modules: modules}), state}
    end
  end

  defp handle("set_param", m, state) do
    with :ok <- may_control(m, state),
         {:ok, robot} <- robot(m),
         {:ok, name} <- string(m, "module"),
         {:ok, key} <- string(m, "key"),
         {:ok, value} <- param_value(m),
         :ok <- wrap(m, Control.set_param(robot, name, key, value, state.by)) do
      {:ok, ok(m), state}
    end
  end

  # the black box: its dumps, a dump now, the timeline of its last minute

  defp handle("dumps", m, state) do
    with {:ok, robot} <- robot(m) do
      list = Dumps.list(robot)
      reply = Map.merge(list, %{op: :dumps, id: m["id"], robot: robot})
      {:ok, encode(reply), state}
    end
  end

  defp handle("dump", m, state) do
    with :ok <- may_control(m, state),
         {:ok, robot} <- robot(m),
         :ok <- wrap(m, Dumps.request(robot, state.by)) do
      {:ok, ok(m), state}
    end
  end

  defp handle("timeline", m, state) do
    with {:ok, robot} <- robot(m) do
      state = close_timeline(state)

      case Timeline.open(robot, self()) do
        {:ok, pid, summary} ->
          reply = Map.merge(summary, %{op: :timeline, id: m["id"]})
          {:ok, encode(reply), %{state | timeline: %{pid: pid, robot: robot}}}

        {:error, reason} ->
          {:error, m["id"], reason}
      end
    end
  end

  defp handle("timeline_frame", m, %{timeline: %{pid: pid, robot: robot}} = state) do
    with {:ok, _} <- number(m, "at", 1.0e15),
         at = m["at"],
         {:ok, have} <- have_map(m),
         {:ok, body} <- wrap(m, Timeline.frame(pid, at, have)) do
      head = [~s({"op":"timeline_frame","id":), encode(m["id"]), ~s(,"robot":)]
      {:ok, [head, encode(robot), ?,, body, ?}], state}
    end
  end

  defp handle("timeline_frame", m, _state),
    do: {:error, m["id"], "no timeline is open: open one (op timeline) first"}

  defp handle("timeline_close", m, state), do: {:ok, ok(m), close_timeline(state)}

  defp handle("query", m, state) do
    with {:ok, template} <- template(m) do
      tuples = Blackboard.rd_all(template)
      {:ok, encode(%{op: :result, id: m["id"], tuples: Enum.take(tuples, 500)}), state}
    end
  end

  defp handle("tail", m, state) do
    with {:ok, id} <- tail_id(m),
         :ok <-
           if(map_size(state.tails) < @max_tails,
             do: :ok,
             else: {:error, id, "at most #{@max_tails} tails"}
           ),
         {:ok, template} <- template(m) do
      state = untail(id, state)
      {:ok, ref} = Blackboard.subscribe(template)
      tail = %{ref: ref, window: System.monotonic_time(:millisecond), count: 0}
      {:ok, ok(m), %{state | tails: Map.put(state.tails, id, tail)}}
    end
  end

  defp handle("untail", m, state) do
    with {:ok, id} <- tail_id(m), do: {:ok, ok(m), untail(id, state)}
  end

  defp handle(nil, m, _state), do: {:error, m["id"], "a message needs an \"op\""}
  defp handle(op, m, _state), do: {:error, m["id"], "unknown op #{inspect(op)}"}

  defp close_timeline(%{timeline: nil} = state), do: state

  defp close_timeline(%{timeline: %{pid: pid}} = state) do
    Timeline.close(pid)
    %{state | timeline: nil}
  end

  ## checks

  # the map the page has: an integer a frame gave, or none
  defp have_map(%{"map" => id}) when is_integer(id), do: {:ok, id}
  defp have_map(%{"map" => nil}), do: {:ok, nil}
  defp have_map(m) when not is_map_key(m, "map"), do: {:ok, nil}

  defp have_map(m),
    do: {:error, m["id"], "map is the integer a frame gave, or null, not #{inspect(m["map"])}"}

  defp may_control(m, state) do
    if state.control,
      do: :ok,
      else: {:error, m["id"], "#{m["op"]} needs the access token (this page is read-only)"}
  end

  defp robot(m) do
    case Control.robot(m["robot"]) do
      {:ok, robot} -> {:ok, robot}
      {:error, reason} -> {:error, m["id"], reason}
    end
  end

  # a number no larger than `max` in size (an integer of 5,000 digits is
  # refused here, not by the arithmetic it would break further on)
  defp number(m, field, max) do
    case m[field] do
      x when is_number(x) and abs(x) <= max ->
        {:ok, x * 1.0}

      x when is_number(x) ->
        {:error, m["id"], "#{field} must be a number from #{-max} to #{max}"}

      other ->
        {:error, m["id"],
         "#{field} must be a number, not #{inspect(other, limit: 5, printable_limit: 40)}"}
    end
  end

  # a param's value: a number, a boolean or a short string
  defp param_value(%{"value" => v}) when is_number(v) or is_boolean(v), do: {:ok, v}
  defp param_value(%{"value" => v}) when is_binary(v) and byte_size(v) <= 256, do: {:ok, v}

  defp param_value(m),
    do:
      {:error, m["id"],
       "set_param needs \"value\": a number, true or false, or a string of at most 256 bytes"}

  defp string(m, field) do
    case m[field] do
      s when is_binary(s) -> {:ok, s}
      other -> {:error, m["id"], "#{field} must be a string, not #{inspect(other)}"}
    end
  end

  # a point within 100 km of the origin, or the name of a waypoint or place
  # the robots know (never a new atom)
  defp target(%{"x" => _, "y" => _} = m) do
    with {:ok, x} <- number(m, "x", 100_000), {:ok, y} <- number(m, "y", 100_000) do
      {:ok, {x, y}}
    end
  end

  defp target(%{"waypoint" => name} = m) when is_binary(name) and byte_size(name) <= 128 do
    if name in known_places(),
      do: {:ok, String.to_existing_atom(name)},
      else: {:error, m["id"], "no waypoint or place #{inspect(name)}"}
  end

  defp target(m), do: {:error, m["id"], "a goal needs numbers x and y, or a waypoint name"}

  # the waypoints, rooms and corridors of the dashboard's world, and the
  # places of the maps the robots learned
  defp known_places do
    learned =
      for Tuples.topology(_robot, %{places: places}) <- Blackboard.rd_all(Tuples.topology()),
          {name, _} <- places,
          do: to_string(name)

    Telemetry.world_places() ++ learned
  end

  defp template(%{"template" => list} = m)
       when is_list(list) and list != [] and length(list) <= 16 do
    {:ok, list |> Enum.map(&template_element/1) |> List.to_tuple()}
  rescue
    e in ArgumentError -> {:error, m["id"], Exception.message(e)}
  end

  defp template(m), do: {:error, m["id"], "a template is a non-empty list of at most 16 elements"}

  defp template_element("_"), do: :_

  defp template_element(s) when is_binary(s) do
    String.to_existing_atom(s)
  rescue
    ArgumentError -> s
  end

  defp template_element(x) when is_number(x), do: x
  defp template_element(nil), do: nil
  defp template_element(b) when is_boolean(b), do: b

  defp template_element(other),
    do:
      raise(
        ArgumentError,
        "a template element is a string, a number or \"_\", not #{inspect(other)}"
      )

  defp tail_id(%{"id" => id}) when is_integer(id) or is_binary(id), do: {:ok, id}
  defp tail_id(m), do: {:error, m["id"], "a tail needs an id (a number or a string)"}

  defp untail(id, state) do
    case Map.pop(state.tails, id) do
      {nil, _} ->
        state

      {tail, tails} ->
        Blackboard.unsubscribe(tail.ref)
        %{state | tails: tails}
    end
  end

  defp object(m) when is_map(m), do: {:ok, m}
  defp object(_), do: {:error, "a message is a JSON object"}

  defp wrap(_m, :ok), do: :ok
  defp wrap(_m, {:ok, x}), do: {:ok, x}
  defp wrap(m, {:error, reason}), do: {:error, m["id"], reason}

  ## replies

  defp ok(m), do: encode(%{op: :ok, id: m["id"]})
  defp error(id, message), do: encode(%{op: :error, id: id, message: message})
  defp encode(map), do: JSON.encode!(map)

  # the id of a message we could not read, if it is readable at all
  defp id_of(text) do
    case JSON.decode(text) do
      {:ok, %{"id" => id}} -> id
      _ -> nil
    end
  end

  defp format_ip(nil), do: "?"
  defp format_ip(ip) when is_tuple(ip), do: ip |> :inet.ntoa() |> to_string()
  defp format_ip(other), do: inspect(other)
end
