defmodule ThinkingCap.Sim.Core.Region do
  @moduledoc false
  # One node's part of a simulation spread over nodes (the `:nodes`
  # option): the node's own copy of the static world (the ray caster is a
  # NIF resource, which cannot cross nodes) and the shards that step the
  # robots of the node's region. At each step the coordinator (Core.Server)
  # sends the bodies this region's robots can touch or see: its own and
  # the ghosts, the robots and walkers of other regions within reach of
  # its own. The region puts them in its ray caster and tells its shards
  # to move. Its shards answer the region, which sends the coordinator
  # one message for them all at each phase (their moves, then their
  # bodies), and passes the coordinator's word to sense on to them: a
  # step costs a few messages between nodes, not a few per shard (125
  # shards of 16 robots sent 250 a step, most of the coordinator's CPU).
  use GenServer

  alias ThinkingCap.Sim.{Raycast, World}
  alias ThinkingCap.Sim.Core.Shard

  @doc """
  Starts a region on this node, not linked (it is called over `:erpc`;
  the coordinator links to it). Options: `:server` (the coordinator),
  `:world` (a WDF path or a `ThinkingCap.Config.WDF`), `:shards`, `:dt`,
  `:seed`, `:publish`.
  """
  def start(opts), do: GenServer.start(__MODULE__, opts)

  @impl true
  def init(opts) do
    with {:ok, world} <- world(opts[:world]) do
      counters = :counters.new(2, [:write_concurrency])

      shard_opts = [
        server: self(),
        dt: opts[:dt],
        seed: opts[:seed],
        publish: opts[:publish],
        world: world,
        counters: counters
      ]

      state = %{
        world: world,
        server: opts[:server],
        shard_opts: shard_opts,
        counters: counters,
        shards: [],
        waiting: nil
      }

      {:ok, start_shards(state, opts[:shards] || System.schedulers_online())}
    else
      {:error, message} -> {:stop, message}
    end
  end

  defp world(%ThinkingCap.Config.WDF{} = wdf), do: World.from_wdf(wdf)
  defp world(path) when is_binary(path), do: World.load(path)

  defp world(other),
    do: {:error, "ThinkingCap.Sim: across nodes, world: #{inspect(other, limit: 3)} is not a WDF"}

  defp start_shards(state, n) do
    opts = Keyword.put(state.shard_opts, :world, state.world)

    new =
      for _ <- 1..n//1 do
        {:ok, pid} = Shard.start_link(opts)
        pid
      end

    %{state | shards: state.shards ++ new}
  end

  @impl true
  def handle_call(:shards, _from, state), do: {:reply, state.shards, state}

  def handle_call({:grow, n}, _from, state) do
    grown = start_shards(state, n)
    {:reply, Enum.drop(grown.shards, length(state.shards)), grown}
  end

  # handovers between this node's shards (Server's regrouping), in
  # order: `[{handover, {from_records, to_records}}]`
  def handle_call({:hand_over, handovers}, _from, state) do
    done =
      for {from, to, ids} = handover <- handovers,
          do: {handover, GenServer.call(from, {:give, ids, to}, 60_000)}

    {:reply, done, state}
  end

  def handle_call(:counters, _from, state),
    do: {:reply, {:counters.get(state.counters, 1), :counters.get(state.counters, 2)}, state}

  def handle_call({:set_door, door, open?}, _from, state) do
    case World.set_door(state.world, door, open?) do
      {:ok, world} ->
        Enum.each(state.shards, &GenServer.cast(&1, {:world, world}))
        {:reply, :ok, %{state | world: world}}

      {:error, message} ->
        {:reply, {:error, message}, state}
    end
  end

  # the doors as given, then every shard's robots back at their start:
  # %{shard => records}
  def handle_call({:reset, doors}, _from, state) do
    world =
      Enum.reduce(doors, state.world, fn {name, open?}, w ->
        {:ok, w} = World.set_door(w, name, open?)
        w
      end)

    records = Map.new(state.shards, &{&1, GenServer.call(&1, {:reset, world}, 30_000)})
    {:reply, records, %{state | world: world}}
  end

  @impl true
  # a step's first phase: this region's bodies (`n` ids in all), then the
  # shards move
  def handle_info({:move, ref, n, bodies}, state) do
    :ok = Raycast.set_bodies_packed(state.world.raycast, n, bodies)
    Enum.each(state.shards, &GenServer.cast(&1, {:move, ref}))
    {:noreply, %{state | waiting: {:moved, ref, length(state.shards), []}}}
  end

  # the second phase: the bodies where they stand after the moves (and
  # the walkers' step), then the shards sense
  def handle_info({:sense, ref, step, time, taken_back, n, bodies}, state) do
    :ok = Raycast.set_bodies_packed(state.world.raycast, n, bodies)
    Enum.each(state.shards, &GenServer.cast(&1, {:sense, ref, step, time, taken_back}))
    {:noreply, %{state | waiting: {:stepped, ref, length(state.shards), []}}}
  end

  # the shards' answers, sent on together once all are in
  def handle_info({:moved, ref, _shard, moves}, %{waiting: {:moved, ref, left, acc}} = state),
    do: {:noreply, answered(state, :moved, ref, left, [moves | acc])}

  def handle_info(
        {:stepped, ref, shard, records},
        %{waiting: {:stepped, ref, left, acc}} = state
      ),
      do: {:noreply, answered(state, :stepped, ref, left, [{shard, records} | acc])}

  def handle_info(_message, state), do: {:noreply, state}

  defp answered(state, phase, ref, 1, acc) do
    message =
      case phase do
        :moved -> {:moved, ref, node(), IO.iodata_to_binary(acc)}
        :stepped -> {:stepped_all, ref, acc}
      end

    send(state.server, message)
    %{state | waiting: nil}
  end

  defp answered(state, phase, ref, left, acc),
    do: %{state | waiting: {phase, ref, left - 1, acc}}
end
