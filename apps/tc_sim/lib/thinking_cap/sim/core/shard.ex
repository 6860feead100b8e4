defmodule ThinkingCap.Sim.Core.Shard do
  @moduledoc false
  # Owns some of the simulation's robots and steps them when the server
  # says so; the shards of a simulation step in parallel, one per
  # scheduler. Readings go where each robot's sink says: its in-process
  # controller, its owner process (a `ThinkingCap.Sim.Robot` driver), and
  # the blackboard when the simulation publishes.
  use GenServer

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Sim.{Raycast, World}
  alias ThinkingCap.Sim.Core.Body
  alias ThinkingCap.Tuples
  require Tuples

  def start_link(opts), do: GenServer.start_link(__MODULE__, opts)

  @impl true
  def init(opts) do
    {:ok,
     %{
       server: opts[:server],
       dt: opts[:dt],
       seed: opts[:seed],
       publish: opts[:publish],
       truth_every: max(1, round(0.1 / opts[:dt])),
       world: opts[:world],
       counters: opts[:counters],
       bodies: %{},
       before: %{}
     }}
  end

  @impl true
  # add, remove and teleport answer with the shard's body records
  def handle_call({:add, spec}, _from, state) do
    body = Body.new(spec, state.dt)
    state = put_in(state.bodies[spec.id], body)
    {:reply, {:ok, records(state.bodies)}, state}
  end

  def handle_call({:remove, id}, _from, state) do
    state = %{state | bodies: Map.delete(state.bodies, id)}
    {:reply, {:ok, records(state.bodies)}, state}
  end

  # a handover of robots to another shard (Regions): their whole state
  # hands robots over to another shard itself: their bodies go from
  # shard to shard (on one node, never through the coordinator's node)
  def handle_call({:give, ids, to}, _from, state) do
    {taken, bodies} = Map.split(state.bodies, ids)
    taken = Enum.map(ids, &Map.fetch!(taken, &1))
    {:ok, to_records} = GenServer.call(to, {:put, taken}, 30_000)
    {:reply, {records(bodies), to_records}, %{state | bodies: bodies}}
  end

  def handle_call({:put, bodies}, _from, state) do
    bodies = Enum.reduce(bodies, state.bodies, &Map.put(&2, &1.id, &1))
    {:reply, {:ok, records(bodies)}, %{state | bodies: bodies}}
  end

  def handle_call({:teleport, id, {x, y, _} = pose}, _from, state) do
    case state.bodies do
      %{^id => body} ->
        if World.free?(state.world, {x, y}, body.radius, body.index) do
          state = put_in(state.bodies[id], %{body | pose: pose})
          {:reply, {:ok, records(state.bodies)}, state}
        else
          {:reply, {:error, {:occupied, pose}}, state}
        end

      _ ->
        {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:attach, id, owner}, _from, state) do
    case state.bodies do
      %{^id => body} ->
        sink = {:owner, owner}
        body = %{body | sink: sink, spec: %{body.spec | sink: sink}}
        {:reply, :ok, put_in(state.bodies[id], body)}

      _ ->
        {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:update_cstate, id, fun}, _from, state) do
    case state.bodies do
      %{^id => body} ->
        {:reply, :ok, put_in(state.bodies[id], %{body | cstate: fun.(body.cstate)})}

      _ ->
        {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:get, id, key}, _from, state) do
    case state.bodies do
      %{^id => body} -> {:reply, {:ok, Map.fetch!(body, key)}, state}
      _ -> {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:reset, world}, _from, state) do
    bodies = Map.new(state.bodies, fn {id, b} -> {id, Body.new(b.spec, state.dt)} end)
    {:reply, records(bodies), %{state | bodies: bodies, world: world}}
  end

  @impl true
  def handle_cast({:command, id, command}, state) do
    case state.bodies do
      %{^id => body} -> {:noreply, put_in(state.bodies[id], Body.command(body, command))}
      _ -> {:noreply, state}
    end
  end

  def handle_cast({:world, world}, state), do: {:noreply, %{state | world: world}}

  # A step in two phases. First every robot moves (each checks the walls
  # and the other robots where they stood); the server then takes back the
  # moves that ran two robots into each other, and every robot senses and
  # runs its controller.
  def handle_cast({:move, ref}, state) do
    {moved, moves} = move_all(Map.to_list(state.bodies), state, [], [])
    send(state.server, {:moved, ref, self(), IO.iodata_to_binary(moves)})
    {:noreply, %{state | bodies: :maps.from_list(moved), before: state.bodies}}
  end

  def handle_cast({:sense, ref, step, time, taken_back}, state) do
    taken_back = if MapSet.size(taken_back) == 0, do: nil, else: taken_back
    at = {step, time, taken_back}

    {sensed, rays, blocked, records} =
      sense_all(Map.to_list(state.bodies), at, state, [], 0, 0, [])

    if rays > 0, do: :counters.add(state.counters, 1, rays)
    if blocked > 0, do: :counters.add(state.counters, 2, blocked)
    send(state.server, {:stepped, ref, self(), IO.iodata_to_binary(records)})
    {:noreply, %{state | bodies: :maps.from_list(sensed), before: %{}}}
  end

  # One pass over the robots for each phase, recursion rather than
  # closures: these run for every robot at every step. The moves and the
  # body records keep the robots' order.
  defp move_all([], _state, moved, moves), do: {moved, :lists.reverse(moves)}

  defp move_all([{id, body} | rest], state, moved, moves) do
    b = Body.move(body, state.world, state.dt)
    {x0, y0, _} = body.pose
    {x1, y1, _} = b.pose
    move = Raycast.move_record(b.index, x0, y0, x1, y1, b.radius)
    move_all(rest, state, [{id, b} | moved], [move | moves])
  end

  defp sense_all([], _at, _state, sensed, rays, blocked, records),
    do: {sensed, rays, blocked, :lists.reverse(records)}

  defp sense_all(
         [{id, body} | rest],
         {step, time, taken_back} = at,
         state,
         sensed,
         rays,
         blocked,
         records
       ) do
    body =
      if taken_back != nil and MapSet.member?(taken_back, body.index),
        do: Body.block(state.before[id], body),
        else: body

    body = sense_body(body, step, time, state)
    %{pose: {x, y, _}, bumped: bumped} = body
    record = Raycast.body_record(body.index, x, y, body.radius)
    blocked = if bumped, do: blocked + 1, else: blocked

    sense_all(rest, at, state, [{id, body} | sensed], rays + body.rays, blocked, [
      record | records
    ])
  end

  defp records(bodies) do
    for {_id, %{pose: {x, y, _}} = b} <- bodies,
        into: <<>>,
        do: Raycast.body_record(b.index, x, y, b.radius)
  end

  defp sense_body(body, step, time, state) do
    {readings, body} = Body.sense(body, state.world, step, time, state.seed, state.publish)

    readings =
      if rem(step, state.truth_every) == 0,
        do: [{:sim_pose, %{pose: body.pose, stamp: time}} | readings],
        else: readings

    deliver(body, readings, state.publish)
    Body.control(body, readings)
  end

  defp deliver(_body, [], _publish), do: :ok

  defp deliver(body, readings, publish) do
    case body.sink do
      {:owner, pid} -> send(pid, {:tc_sim, :readings, body.id, readings})
      _ -> :ok
    end

    cond do
      publish -> publish_all(readings, body.id)
      MapSet.size(body.publish) == 0 -> :ok
      true -> publish_some(readings, body)
    end
  end

  # (recursion: this runs for every robot at every step)
  defp publish_all([], _id), do: :ok

  defp publish_all([{sensor, payload} | rest], id) do
    Blackboard.out(Tuples.reading(sensor, id, payload), key: {sensor, id})
    publish_all(rest, id)
  end

  defp publish_some(readings, body) do
    for {sensor, payload} <- readings,
        MapSet.member?(body.publish, sensor),
        do: Blackboard.out(Tuples.reading(sensor, body.id, payload), key: {sensor, body.id})

    :ok
  end
end
