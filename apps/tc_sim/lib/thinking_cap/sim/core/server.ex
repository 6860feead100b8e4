defmodule ThinkingCap.Sim.Core.Server do
  @moduledoc false
  # The simulation's clock and world: steps the shards (in parallel),
  # collects where every robot now stands and hands that to the ray caster
  # as the bodies the others see; answers the public API of ThinkingCap.Sim.
  # Robots' bodies travel as packed records (Raycast.body_record/4), one
  # binary per shard, so that the per-step work here does not decode a
  # term per robot.
  use GenServer
  require Logger

  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim.{Raycast, World}
  alias ThinkingCap.Sim.Core.{Contacts, Ghosts, Region, Regions, Shard, Walkers}

  # robots per shard before more shards start: a shard rebuilds its
  # robots' state every step, and a large process heap makes each garbage
  # collection copy more (10 x 500 robots steps ~3x slower than 20 x 50);
  # small shards also spread a fleet evenly over the schedulers (100
  # robots in 32 + 32 + 32 + 4 kept one core waiting a quarter of a step)
  @per_shard 16
  # steps between two regroupings of the robots by place (Regions)
  @regroup_every 50
  # added to the longest sensor reach for the ghosts of a region: a move's
  # length within a step, with room to spare
  @ghost_slack 0.5

  def start_link(opts) do
    case Keyword.fetch(opts, :name) do
      {:ok, name} -> GenServer.start_link(__MODULE__, opts, name: name)
      :error -> GenServer.start_link(__MODULE__, opts)
    end
  end

  def start(opts) do
    case Keyword.fetch(opts, :name) do
      {:ok, name} -> GenServer.start(__MODULE__, opts, name: name)
      :error -> GenServer.start(__MODULE__, opts)
    end
  end

  @impl true
  def init(opts) do
    with {:ok, mode} <- one_of(opts, :mode, [:realtime, :fast], :realtime),
         {:ok, dt} <- positive(opts, :step, 0.01),
         {:ok, speed} <- positive(opts, :speed, 1.0),
         {:ok, seed} <- integer(opts, :seed, 1),
         {:ok, n_shards} <- count(opts, :shards, System.schedulers_online()),
         {:ok, per_shard} <- count(opts, :per_shard, @per_shard),
         {:ok, regroup_every} <- count(opts, :regroup_every, @regroup_every),
         {:ok, world} <- world(Keyword.fetch(opts, :world)),
         {:ok, nodes} <- nodes(opts),
         {:ok, borders} <- borders(opts, nodes, world) do
      counters = :counters.new(2, [:write_concurrency])

      shard_opts = [
        server: self(),
        dt: dt,
        seed: seed,
        publish: Keyword.get(opts, :publish, false),
        world: world,
        counters: counters
      ]

      case start_shards(nodes, opts, n_shards, shard_opts) do
        {:ok, shards, regions} ->
          start_state(opts, %{
            shards: shards,
            regions: regions,
            borders: borders,
            shard_opts: shard_opts,
            n_shards: n_shards,
            per_shard: per_shard,
            regroup_every: regroup_every,
            world: world,
            mode: mode,
            dt: dt,
            speed: speed,
            seed: seed,
            counters: counters
          })

        {:error, message} ->
          {:stop, message}
      end
    else
      {:error, message} -> {:stop, message}
    end
  end

  defp start_state(opts, s) do
    %{shards: shards, shard_opts: shard_opts, n_shards: n_shards, per_shard: per_shard} = s
    %{regroup_every: regroup_every, world: world, mode: mode, dt: dt, speed: speed} = s
    %{seed: seed, counters: counters} = s

    state = %{
      shard_opts: shard_opts,
      # shards start this many at a time, each taking per_shard robots
      grow_by: n_shards,
      per_shard: per_shard,
      regroup_every: regroup_every,
      # robots per shard
      load: Map.new(shards, &{&1, 0}),
      world: world,
      initial_doors: world.doors,
      mode: mode,
      dt: dt,
      speed: speed,
      seed: seed,
      step: 0,
      running: Keyword.get(opts, :running, true),
      shards: List.to_tuple(shards),
      robots: %{},
      # shard => its robots' body records
      records: %{},
      free_indexes: [],
      next_index: 0,
      counters: counters,
      lagged: 0,
      handovers: 0,
      activity: nil,
      target: nil,
      started_at: System.monotonic_time(),
      walkers: %{},
      # across nodes: [{node, region}] in node order, shards to start at
      # a time on each node, the strips' borders, the ghosts' reach
      regions: s.regions,
      grow_by_node: grow_by_node(shards),
      borders: s.borders,
      reach: 0.0,
      node_handovers: 0,
      ghosts: 0
    }

    case start_walkers(state, Keyword.get(opts, :walkers, []), world) do
      {:ok, state} -> {:ok, schedule(state)}
      {:error, message} -> {:stop, "ThinkingCap.Sim: " <> message}
    end
  end

  defp grow_by_node(shards),
    do: shards |> Enum.group_by(&node/1) |> Map.new(fn {n, list} -> {n, length(list)} end)

  # the shards of a one-node simulation, or a region on each node (its
  # own world and shards: `:shards` per node, default its schedulers)
  defp start_shards(nil, _opts, n_shards, shard_opts) do
    shards =
      for _ <- 1..n_shards do
        {:ok, pid} = Shard.start_link(shard_opts)
        pid
      end

    {:ok, shards, nil}
  end

  defp start_shards(nodes, opts, _n_shards, shard_opts) do
    region_opts = [
      server: self(),
      world: region_world(Keyword.fetch!(opts, :world)),
      shards: opts[:shards],
      dt: shard_opts[:dt],
      seed: shard_opts[:seed],
      publish: shard_opts[:publish]
    ]

    Enum.reduce_while(nodes, {:ok, []}, fn node, {:ok, acc} ->
      case start_region(node, region_opts) do
        {:ok, pid} -> {:cont, {:ok, [{node, pid} | acc]}}
        {:error, message} -> {:halt, {:error, message, acc}}
      end
    end)
    |> case do
      {:ok, regions} ->
        regions = Enum.reverse(regions)
        shards = Enum.flat_map(regions, fn {_node, pid} -> GenServer.call(pid, :shards) end)
        {:ok, shards, regions}

      {:error, message, started} ->
        for {_node, pid} <- started, do: Process.exit(pid, :shutdown)
        {:error, message}
    end
  end

  defp start_region(node, opts) do
    case :erpc.call(node, Region, :start, [opts], 60_000) do
      {:ok, pid} ->
        Process.link(pid)
        {:ok, pid}

      {:error, reason} ->
        {:error, "ThinkingCap.Sim: node #{inspect(node)}: #{reason_text(reason)}"}
    end
  catch
    :error, {:erpc, reason} ->
      {:error, "ThinkingCap.Sim: node #{inspect(node)} cannot be reached (#{inspect(reason)})"}

    :error, {:exception, e, _} ->
      {:error, "ThinkingCap.Sim: node #{inspect(node)}: #{Exception.message(e)}"}
  end

  defp reason_text(reason) when is_binary(reason), do: reason
  defp reason_text(reason), do: inspect(reason)

  # a region builds its own world: from the WDF (a path, or the WDF a
  # world was built from)
  defp region_world(%World{wdf: wdf}), do: wdf
  defp region_world(path) when is_binary(path), do: Path.expand(path)
  defp region_world(wdf), do: wdf

  defp nodes(opts) do
    case Keyword.get(opts, :nodes) do
      nil ->
        {:ok, nil}

      [_ | _] = nodes ->
        if Enum.all?(nodes, &is_atom/1) and nodes == Enum.uniq(nodes),
          do: {:ok, nodes},
          else: {:error, "ThinkingCap.Sim: nodes: #{inspect(nodes)} is not a list of nodes"}

      other ->
        {:error, "ThinkingCap.Sim: nodes: #{inspect(other, limit: 5)} is not a list of nodes"}
    end
  end

  defp borders(_opts, nil, _world), do: {:ok, []}

  defp borders(opts, nodes, world) do
    n = length(nodes)

    case Keyword.get(opts, :borders) do
      nil ->
        case world.bounds do
          {{x0, _}, {x1, _}} -> {:ok, Ghosts.even_borders({x0, x1}, n)}
          nil -> {:ok, Ghosts.even_borders({-1.0, 1.0}, n)}
        end

      list when is_list(list) ->
        if length(list) == n - 1 and Enum.all?(list, &is_number/1) and list == Enum.sort(list),
          do: {:ok, Enum.map(list, &(&1 * 1.0))},
          else:
            {:error,
             "ThinkingCap.Sim: borders: #{inspect(list, limit: 5)} is not #{n - 1} ascending " <>
               "numbers (one between each two of the #{n} nodes)"}

      other ->
        {:error, "ThinkingCap.Sim: borders: #{inspect(other, limit: 5)} is not a list of numbers"}
    end
  end

  # the walkers given and those of the WDF's crowd section, or the first
  # error (a crowd with no room, a walker not free or given twice)
  defp start_walkers(state, given, world) do
    Enum.reduce_while(given ++ crowd(world), {:ok, state}, fn {id, wopts}, {:ok, state} ->
      case add_walker(state, id, wopts) do
        {:ok, state} -> {:cont, {:ok, state}}
        {:error, message} -> {:halt, {:error, message}}
      end
    end)
  rescue
    e in ArgumentError -> {:error, Exception.message(e)}
  end

  # the walkers of the WDF's crowd section
  defp crowd(%World{wdf: %{crowd: %{} = crowd}} = world),
    do: ThinkingCap.Sim.Crowd.walkers(world, Map.to_list(crowd))

  defp crowd(_world), do: []

  defp world({:ok, %World{} = world}), do: {:ok, world}
  defp world({:ok, %ThinkingCap.Config.WDF{} = wdf}), do: World.from_wdf(wdf)
  defp world({:ok, path}) when is_binary(path), do: World.load(path)
  defp world(:error), do: {:error, "ThinkingCap.Sim: give world: a WDF path or a WDF"}

  defp world({:ok, other}),
    do: {:error, "ThinkingCap.Sim: world: #{inspect(other, limit: 5)} is not a WDF"}

  defp one_of(opts, key, allowed, default) do
    value = Keyword.get(opts, key, default)

    if value in allowed,
      do: {:ok, value},
      else:
        {:error, "ThinkingCap.Sim: #{key}: #{inspect(value)} is not one of #{inspect(allowed)}"}
  end

  defp positive(opts, key, default) do
    case Keyword.get(opts, key, default) do
      v when is_number(v) and v > 0 -> {:ok, v * 1.0}
      v -> {:error, "ThinkingCap.Sim: #{key}: #{inspect(v)} is not a positive number"}
    end
  end

  defp integer(opts, key, default) do
    case Keyword.get(opts, key, default) do
      v when is_integer(v) -> {:ok, v}
      v -> {:error, "ThinkingCap.Sim: #{key}: #{inspect(v)} is not an integer"}
    end
  end

  defp count(opts, key, default) do
    case Keyword.get(opts, key, default) do
      v when is_integer(v) and v > 0 -> {:ok, v}
      v -> {:error, "ThinkingCap.Sim: #{key}: #{inspect(v)} is not a positive integer"}
    end
  end

  defp ok_or({:ok, value}, _reason), do: {:ok, value}
  defp ok_or(:error, reason), do: {:error, reason}

  # across nodes a region's world holds only the bodies near its robots:
  # a robot carried elsewhere is checked against every body here first
  defp free_here(%{regions: nil}, _shard, _id, _index, _pose), do: :ok

  defp free_here(state, shard, id, index, {x, y, _} = pose) do
    {:ok, radius} = GenServer.call(shard, {:get, id, :radius})

    if World.free?(state.world, {x, y}, radius, index),
      do: :ok,
      else: {:error, {:occupied, pose}}
  end

  defp occupied(pose), do: "ThinkingCap.Sim: #{inspect(pose)} overlaps a wall or a robot"

  ## Stepping

  # :fast mode steps through its own mailbox (so calls are answered between
  # steps); :realtime mode on the timing worker's releases.
  defp schedule(%{mode: :fast, running: true} = state) do
    send(self(), :tick)
    state
  end

  defp schedule(%{mode: :realtime, activity: nil} = state) do
    name = :"tc_sim_#{System.unique_integer([:positive])}"

    :ok =
      ThinkingCap.Cycle.add(name,
        period: state.dt / state.speed,
        deadline: state.dt / state.speed,
        priority: 60,
        fallback: :none,
        owner: self()
      )

    %{state | activity: name}
  end

  defp schedule(state), do: state

  @impl true
  def handle_info(:tick, %{mode: :fast, running: true} = state) do
    state = do_step(state)
    send(self(), :tick)
    {:noreply, state}
  end

  def handle_info(:tick, state), do: {:noreply, state}

  def handle_info({:tc_cycle, :release, name, release}, %{activity: name} = state) do
    {release, skipped} = newest_release(name, release, 0)
    state = %{state | lagged: state.lagged + skipped}
    state = if state.running, do: do_step(state), else: state
    ThinkingCap.Cycle.result(release, :ok)
    {:noreply, state}
  end

  def handle_info({:tc_cycle, :applied, _name, _event}, state), do: {:noreply, state}

  def handle_info({:stepped, _ref, _shard, _records}, state), do: {:noreply, state}
  def handle_info({:stepped_all, _ref, _records}, state), do: {:noreply, state}
  def handle_info({:moved, _ref, _from, _moves}, state), do: {:noreply, state}

  def handle_info(message, state) do
    Logger.debug("ThinkingCap.Sim: unexpected message #{inspect(message, limit: 10)}")
    {:noreply, state}
  end

  defp newest_release(name, release, skipped) do
    receive do
      {:tc_cycle, :release, ^name, newer} -> newest_release(name, newer, skipped + 1)
    after
      0 -> {release, skipped}
    end
  end

  # One step: every shard moves its robots in parallel; the moves that ran
  # two robots into each other are taken back (Contacts); the walkers step
  # among the robots where they now stand; the ray caster (and each
  # region's, across nodes) takes the bodies where they now are; then every
  # shard reads its robots' sensors and runs their controllers in parallel.
  # So a reading sees the other robots and the walkers where they are at
  # its stamp, not where they were a step before.
  defp do_step(state) do
    state = regroup(state)
    ref = make_ref()
    time = state.step * state.dt
    shards = Tuple.to_list(state.shards)
    state = start_moves(state, shards, ref)
    answering = if state.regions, do: length(state.regions), else: length(shards)
    moved = collect_moves(ref, answering, [])
    moves = Enum.map(moved, &elem(&1, 1))
    taken_back = Contacts.taken_back(moves)
    standing = Enum.map(moved, fn {from, bin} -> {from, standing(bin, taken_back)} end)
    robots = IO.iodata_to_binary(Enum.map(standing, &elem(&1, 1)))
    walkers = Walkers.step(state.walkers, discs(robots, state.walkers), state.dt)
    state = %{state | walkers: walkers}
    walker_records = walker_records(walkers)
    bodies = IO.iodata_to_binary([robots | walker_records])
    :ok = Raycast.set_bodies_packed(state.world.raycast, state.next_index, bodies)
    sense = {:sense, ref, state.step, time, taken_back}

    if state.regions do
      own = Enum.group_by(standing, &elem(&1, 0), &elem(&1, 1))
      own = Map.merge(Map.new(state.regions, &{elem(&1, 0), []}), own)
      bodies = Ghosts.bodies(own, IO.iodata_to_binary(walker_records), state.reach)

      for {node, pid} <- state.regions,
          do:
            send(pid, {:sense, ref, state.step, time, taken_back, state.next_index, bodies[node]})
    else
      Enum.each(shards, &GenServer.cast(&1, sense))
    end

    records = collect(ref, answering, state.records)
    %{state | step: state.step + 1, records: records}
  end

  # The first phase of a step. On one node the shards move at once; across
  # nodes each region first gets the bodies it must see (its robots and
  # their ghosts, Ghosts), then tells its shards to move.
  defp start_moves(%{regions: nil} = state, shards, ref) do
    Enum.each(shards, &GenServer.cast(&1, {:move, ref}))
    state
  end

  defp start_moves(state, _shards, ref) do
    own =
      Enum.reduce(state.records, Map.new(state.regions, &{elem(&1, 0), []}), fn {shard, bin},
                                                                                acc ->
        Map.update!(acc, node(shard), &[bin | &1])
      end)

    walkers =
      for {_id, %{at: {x, y}} = w} <- state.walkers,
          into: <<>>,
          do: Raycast.body_record(w.index, x, y, w.radius)

    bodies = Ghosts.bodies(own, walkers, state.reach)
    for {node, pid} <- state.regions, do: send(pid, {:move, ref, state.next_index, bodies[node]})
    held = bodies |> Map.values() |> Enum.map(&Ghosts.count/1) |> Enum.sum()
    %{state | ghosts: held - map_size(state.robots)}
  end

  # Every regroup_every steps, robots near each other go to the same shard
  # (Regions): a shard then casts over one part of the map at a time.
  # Across nodes, a robot first goes to the node of the strip it is in (a
  # handover across a region's border), then to a shard of that node by
  # place.
  defp regroup(%{step: step, regroup_every: every} = state) when rem(step, every) != 0, do: state

  defp regroup(%{regions: [_ | _]} = state) do
    by_index = Map.new(state.robots, fn {id, {index, _shard}} -> {index, id} end)
    current = Map.new(state.robots, fn {id, {_index, shard}} -> {id, shard} end)
    shards = Tuple.to_list(state.shards)

    {within, across} =
      for(
        {_shard, bin} <- state.records,
        <<i::float-native-64, x::float-native-64, y::float-native-64, _::float-native-64 <- bin>>,
        do: {Map.fetch!(by_index, trunc(i)), trunc(i), x, y}
      )
      |> Enum.group_by(fn {_id, _i, x, _y} -> region_node(state, x) end)
      |> Enum.sort()
      |> Enum.flat_map(fn {node, robots} ->
        Regions.plan(robots, Enum.filter(shards, &(node(&1) == node)), current)
      end)
      |> Enum.split_with(fn {from, to, _ids} -> node(from) == node(to) end)

    # the robots that cross a border, after the handovers within nodes
    Enum.reduce(across, hand_over_within(state, within), &hand_over/2)
  end

  defp regroup(state) when tuple_size(state.shards) < 2, do: state

  defp regroup(state) do
    by_index = Map.new(state.robots, fn {id, {index, _shard}} -> {index, id} end)
    current = Map.new(state.robots, fn {id, {_index, shard}} -> {id, shard} end)

    robots =
      for {_shard, bin} <- state.records,
          <<i::float-native-64, x::float-native-64, y::float-native-64,
            _::float-native-64 <- bin>>,
          do: {Map.fetch!(by_index, trunc(i)), trunc(i), x, y}

    robots
    |> Regions.plan(Tuple.to_list(state.shards), current)
    |> Enum.reduce(state, &hand_over/2)
  end

  # The handovers between shards of one node: each region makes its own,
  # the regions at once (one call from here per handover took a round
  # trip between nodes each: seconds for a fleet's first regrouping).
  # Each region's answers come in the order it made them, so the records
  # of a shard are those of its last handover.
  defp hand_over_within(state, []), do: state

  defp hand_over_within(state, handovers) do
    handovers
    |> Enum.group_by(fn {from, _to, _ids} -> node(from) end)
    |> Enum.map(fn {node, list} ->
      {^node, region} = List.keyfind(state.regions, node, 0)
      :gen_server.send_request(region, {:hand_over, list})
    end)
    |> Enum.flat_map(fn request ->
      {:reply, done} = :gen_server.wait_response(request, 60_000)
      done
    end)
    |> Enum.reduce(state, fn {handover, records}, state ->
      handed_over(handover, records, state)
    end)
  end

  defp hand_over({from, to, ids} = handover, state) do
    handed_over(handover, GenServer.call(from, {:give, ids, to}, 60_000), state)
  end

  defp handed_over({from, to, ids}, {from_records, to_records}, state) do
    n = length(ids)

    robots =
      Enum.reduce(ids, state.robots, fn id, acc ->
        Map.update!(acc, id, fn {index, _} -> {index, to} end)
      end)

    %{
      state
      | robots: robots,
        records: state.records |> Map.put(from, from_records) |> Map.put(to, to_records),
        load: state.load |> Map.update!(from, &(&1 - n)) |> Map.update!(to, &(&1 + n)),
        handovers: state.handovers + n,
        node_handovers: state.node_handovers + if(node(from) == node(to), do: 0, else: n)
    }
  end

  # the node whose strip holds x
  defp region_node(state, x) do
    {node, _pid} = Enum.at(state.regions, Ghosts.strip(state.borders, x))
    node
  end

  ## Walkers

  # People (discs) walking routes of points at their speed, back and forth
  # (or round, `loop: true`); one waits while its next step would touch a
  # robot or another walker. They are bodies of the ray caster, as robots
  # are: every sensor sees them, and a robot moving into one is stopped.
  defp add_walker(state, id, opts) do
    with :ok <- new_walker(state, id),
         {:ok, route} <- route(state.world, Keyword.get(opts, :route)),
         {:ok, speed} <- positive(opts, :speed, 0.8),
         {:ok, radius} <- positive(opts, :radius, 0.25),
         {x, y} = hd(route),
         true <-
           World.free?(state.world, {x, y}, radius) ||
             {:error, "walker #{inspect(id)}: #{inspect({x, y})} is not free"} do
      {index, state} = take_index(state)

      walker = %{
        index: index,
        route: List.to_tuple(route),
        start: {x, y},
        at: {x, y},
        leg: 1,
        dir: 1,
        loop: Keyword.get(opts, :loop, false) == true,
        speed: speed,
        radius: radius
      }

      state = %{state | walkers: Map.put(state.walkers, id, walker)}
      set_bodies(state)
      {:ok, state}
    end
  end

  defp new_walker(state, id) do
    cond do
      Map.has_key?(state.walkers, id) -> {:error, "walker #{inspect(id)} exists already"}
      Map.has_key?(state.robots, id) -> {:error, "#{inspect(id)} is a robot"}
      true -> :ok
    end
  end

  defp route(world, points) when is_list(points) and length(points) >= 2 do
    points
    |> Enum.reduce_while([], fn p, acc ->
      case World.resolve_pose(world, p) do
        {:ok, {x, y, _}} -> {:cont, [{x, y} | acc]}
        {:error, message} -> {:halt, {:error, "walker route: #{message}"}}
      end
    end)
    |> case do
      {:error, _} = error -> error
      list -> {:ok, Enum.reverse(list)}
    end
  end

  defp route(_world, other),
    do: {:error, "walker route: #{inspect(other, limit: 5)} is not a list of two points or more"}

  # Where the robots of a binary of moves stand after them, as body
  # records: a move taken back leaves its robot where it stood. (Gathered
  # as iodata: built by appending, the binary took 5x as long, 1 ms a
  # step for 2,000 robots.)
  defp standing(bin, taken_back) do
    records =
      for <<id::binary-size(8), x0::binary-size(16), x1::binary-size(16),
            r::binary-size(8) <- bin>> do
        <<i::float-native-64>> = id
        if MapSet.member?(taken_back, trunc(i)), do: [id, x0 | r], else: [id, x1 | r]
      end

    IO.iodata_to_binary(records)
  end

  # body records as the walkers' step takes the robots: x, y, radius
  defp discs(_records, walkers) when map_size(walkers) == 0, do: <<>>

  defp discs(records, _walkers),
    do: for(<<_i::binary-size(8), disc::binary-size(24) <- records>>, into: <<>>, do: disc)

  defp walker_records(walkers) do
    for {_id, %{at: {x, y}} = w} <- walkers, do: Raycast.body_record(w.index, x, y, w.radius)
  end

  defp collect_moves(_ref, 0, moves), do: moves

  # the moves of each shard, or (across nodes) of each region: [{from, binary}]
  defp collect_moves(ref, n, moves) do
    receive do
      {:moved, ^ref, from, more} -> collect_moves(ref, n - 1, [{from, more} | moves])
    end
  end

  defp collect(_ref, 0, records), do: records

  # a shard's records, or (across nodes) a region's for all its shards
  defp collect(ref, n, records) do
    receive do
      {:stepped, ^ref, shard, bin} -> collect(ref, n - 1, Map.put(records, shard, bin))
      {:stepped_all, ^ref, list} -> collect(ref, n - 1, Enum.into(list, records))
    end
  end

  # every robot (its shard's records) and walker to the ray caster; the
  # indexes no body holds are parked far away
  defp set_bodies(state) do
    data = IO.iodata_to_binary([Map.values(state.records) | walker_records(state.walkers)])
    :ok = Raycast.set_bodies_packed(state.world.raycast, state.next_index, data)
  end

  defp run_steps(state, 0), do: state
  defp run_steps(state, n), do: run_steps(do_step(state), n - 1)

  ## API

  @impl true
  def handle_call({:add_robot, id, opts}, _from, state) do
    with :ok <- new_id(state, id),
         {:ok, description} <- description(opts),
         {:ok, pose} <- World.resolve_pose(state.world, Keyword.get(opts, :at)),
         {:ok, sink} <- sink(opts),
         {:ok, publish} <- publish(opts),
         :ok <- free(state, pose, description) do
      {index, state} = take_index(state)

      spec = %{
        id: id,
        index: index,
        description: description,
        pose: pose,
        sink: sink,
        publish: publish,
        seed: Keyword.get(opts, :seed, :erlang.phash2({state.seed, id}))
      }

      {shard, state} = pick_shard(state, pose)
      # the shard starts the robot's controller (a lock-step module stack may
      # build its maps first): within add_robot/3's own 30 s
      {:ok, records} = GenServer.call(shard, {:add, spec}, 28_000)

      state = %{
        state
        | robots: Map.put(state.robots, id, {index, shard}),
          records: Map.put(state.records, shard, records),
          load: Map.update!(state.load, shard, &(&1 + 1)),
          reach: max(state.reach, reach(description))
      }

      set_bodies(state)
      {:reply, :ok, state}
    else
      {:error, message} -> {:reply, {:error, message}, state}
    end
  end

  def handle_call({:remove_robot, id}, _from, state) do
    case state.robots do
      %{^id => {index, shard}} ->
        {:ok, records} = GenServer.call(shard, {:remove, id})

        state = %{
          state
          | robots: Map.delete(state.robots, id),
            records: Map.put(state.records, shard, records),
            free_indexes: [index | state.free_indexes],
            load: Map.update!(state.load, shard, &(&1 - 1))
        }

        set_bodies(state)
        {:reply, :ok, state}

      _ ->
        {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:add_walker, id, opts}, _from, state) do
    case add_walker(state, id, opts) do
      {:ok, state} -> {:reply, :ok, state}
      {:error, message} -> {:reply, {:error, message}, state}
    end
  end

  def handle_call({:remove_walker, id}, _from, state) do
    case Map.pop(state.walkers, id) do
      {nil, _} ->
        {:reply, {:error, :no_walker}, state}

      {w, walkers} ->
        state = %{state | walkers: walkers, free_indexes: [w.index | state.free_indexes]}
        set_bodies(state)
        {:reply, :ok, state}
    end
  end

  def handle_call(:walkers, _from, state),
    do: {:reply, Map.new(state.walkers, fn {id, w} -> {id, w.at} end), state}

  def handle_call(:walker_discs, _from, state) do
    discs = for {_id, %{at: {x, y}} = w} <- Enum.sort(state.walkers), do: {x, y, w.radius}
    {:reply, discs, state}
  end

  def handle_call({:teleport, id, at}, _from, state) do
    with {:ok, {index, shard}} <- Map.fetch(state.robots, id) |> ok_or(:no_robot),
         {:ok, pose} <- World.resolve_pose(state.world, at),
         :ok <- free_here(state, shard, id, index, pose),
         {:ok, records} <- GenServer.call(shard, {:teleport, id, pose}) do
      state = %{state | records: Map.put(state.records, shard, records)}
      set_bodies(state)
      {:reply, :ok, state}
    else
      {:error, {:occupied, pose}} -> {:reply, {:error, occupied(pose)}, state}
      {:error, reason} -> {:reply, {:error, reason}, state}
    end
  end

  def handle_call(:placement, _from, state),
    do: {:reply, Map.new(state.robots, fn {id, {_index, shard}} -> {id, node(shard)} end), state}

  def handle_call({:attach, id, owner}, _from, state) do
    case state.robots do
      %{^id => {_index, shard}} -> {:reply, GenServer.call(shard, {:attach, id, owner}), state}
      _ -> {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:set_door, door, open?}, _from, state) do
    case World.set_door(state.world, door, open?) do
      {:ok, world} when state.regions == nil ->
        Enum.each(Tuple.to_list(state.shards), &GenServer.cast(&1, {:world, world}))
        {:reply, :ok, %{state | world: world}}

      {:ok, world} ->
        for {_node, pid} <- state.regions, do: :ok = GenServer.call(pid, {:set_door, door, open?})
        {:reply, :ok, %{state | world: world}}

      {:error, message} ->
        {:reply, {:error, message}, state}
    end
  end

  def handle_call(:pause, _from, state), do: {:reply, :ok, %{state | running: false}}

  def handle_call(:resume, _from, %{running: true} = state), do: {:reply, :ok, state}

  def handle_call(:resume, _from, state),
    do: {:reply, :ok, schedule(%{state | running: true})}

  def handle_call({:run_steps, n}, _from, state) when is_integer(n) and n > 0,
    do: {:reply, :ok, run_steps(state, n)}

  def handle_call({:run_for, seconds}, _from, state) when is_number(seconds) and seconds >= 0,
    do: {:reply, :ok, run_steps(state, round(seconds / state.dt))}

  def handle_call(:reset, _from, state) do
    world =
      Enum.reduce(state.initial_doors, state.world, fn {name, %{open: open}}, w ->
        {:ok, w} = World.set_door(w, name, open)
        w
      end)

    records =
      case state.regions do
        nil ->
          Map.new(Tuple.to_list(state.shards), fn shard ->
            {shard, GenServer.call(shard, {:reset, world}, 30_000)}
          end)

        regions ->
          doors = Map.new(state.initial_doors, fn {name, %{open: open}} -> {name, open} end)

          regions
          |> Enum.map(fn {_node, pid} -> GenServer.call(pid, {:reset, doors}, 60_000) end)
          |> Enum.reduce(%{}, &Map.merge/2)
      end

    walkers = Map.new(state.walkers, fn {id, w} -> {id, %{w | at: w.start, leg: 1, dir: 1}} end)

    state = %{
      state
      | world: world,
        step: 0,
        records: records,
        lagged: 0,
        walkers: walkers
    }

    set_bodies(state)
    {:reply, :ok, state}
  end

  def handle_call(:time, _from, state), do: {:reply, state.step * state.dt, state}

  def handle_call({:update_cstate, id, fun}, _from, state) do
    case state.robots do
      %{^id => {_index, shard}} ->
        {:reply, GenServer.call(shard, {:update_cstate, id, fun}), state}

      _ ->
        {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call({:get, id, key}, _from, state) do
    case state.robots do
      %{^id => {_index, shard}} -> {:reply, GenServer.call(shard, {:get, id, key}), state}
      _ -> {:reply, {:error, :no_robot}, state}
    end
  end

  def handle_call(:robots, _from, state) do
    robots =
      Map.new(state.robots, fn {id, {_index, shard}} ->
        {:ok, pose} = GenServer.call(shard, {:get, id, :pose})
        {id, pose}
      end)

    {:reply, robots, state}
  end

  def handle_call(:world, _from, state), do: {:reply, state.world, state}

  def handle_call(:status, _from, state) do
    {rays, blocked} =
      Enum.reduce(
        state.regions || [],
        {:counters.get(state.counters, 1), :counters.get(state.counters, 2)},
        fn {_node, pid}, {r, b} ->
          {r2, b2} = GenServer.call(pid, :counters)
          {r + r2, b + b2}
        end
      )

    {:reply,
     %{
       time: state.step * state.dt,
       steps: state.step,
       step: state.dt,
       speed: state.speed,
       mode: state.mode,
       running: state.running,
       robots: map_size(state.robots),
       walkers: map_size(state.walkers),
       shards: tuple_size(state.shards),
       lagged: state.lagged,
       handovers: state.handovers,
       rays: rays,
       blocked: blocked,
       nodes: if(state.regions, do: Enum.map(state.regions, &elem(&1, 0)), else: [node()]),
       node_handovers: state.node_handovers,
       ghosts: state.ghosts
     }, state}
  end

  @impl true
  def handle_cast({:command, id, command}, state) do
    case state.robots do
      %{^id => {_index, shard}} -> GenServer.cast(shard, {:command, id, command})
      _ -> :ok
    end

    {:noreply, state}
  end

  @impl true
  def terminate(_reason, state) do
    if state.activity, do: ThinkingCap.Cycle.remove(state.activity)
    # the world may be built again into another simulation: take the robots out
    Raycast.set_bodies(state.world.raycast, [])
    # a normal stop does not end the linked shards
    for pid <- Tuple.to_list(state.shards), do: Process.exit(pid, :shutdown)
    for {_node, pid} <- state.regions || [], do: Process.exit(pid, :shutdown)
    :ok
  end

  ## Robots

  defp new_id(state, id) do
    cond do
      not is_atom(id) -> {:error, "a robot id is an atom, not #{inspect(id)}"}
      Map.has_key?(state.robots, id) -> {:error, "robot #{inspect(id)} is already in the world"}
      true -> :ok
    end
  end

  defp description(opts) do
    case {opts[:description], opts[:rdf]} do
      {%Description{} = d, _} -> {:ok, d}
      {nil, path} when is_binary(path) -> Description.load(path)
      _ -> {:error, "give rdf: a path or description: a ThinkingCap.Robot.Description"}
    end
  end

  defp sink(opts) do
    case {opts[:controller], opts[:owner]} do
      {nil, nil} -> {:ok, :none}
      {{module, args}, nil} when is_atom(module) -> controller(module, args)
      {module, nil} when is_atom(module) -> controller(module, [])
      {nil, pid} when is_pid(pid) -> {:ok, {:owner, pid}}
      _ -> {:error, "give controller: {module, args} or owner: pid, not both"}
    end
  end

  defp publish(opts) do
    case Keyword.get(opts, :publish, []) do
      list when is_list(list) ->
        if Enum.all?(list, &is_atom/1),
          do: {:ok, MapSet.new(list)},
          else: {:error, "publish: #{inspect(list, limit: 5)} is not a list of sensor names"}

      other ->
        {:error, "publish: #{inspect(other, limit: 5)} is not a list of sensor names"}
    end
  end

  defp controller(module, args) do
    if Code.ensure_loaded?(module) and function_exported?(module, :control, 2),
      do: {:ok, {:controller, module, args}},
      else: {:error, "#{inspect(module)} is not a ThinkingCap.Sim.Controller"}
  end

  defp free(state, {x, y, _} = pose, description) do
    if World.free?(state.world, {x, y}, description.footprint.radius),
      do: :ok,
      else: {:error, "start pose #{inspect(pose)} is not free for a robot of this footprint"}
  end

  # the least loaded shard (the first of them in start order), or, when
  # every shard holds per_shard robots, the first of grow_by new ones (as
  # many as the shards at the start: a multiple of the schedulers by
  # default); a new shard's world is the current one (doors as they are)
  defp pick_shard(%{regions: [_ | _]} = state, {x, _, _}) do
    node = region_node(state, x)
    shards = state.shards |> Tuple.to_list() |> Enum.filter(&(node(&1) == node))
    shard = Enum.min_by(shards, &state.load[&1])

    if state.load[shard] < state.per_shard do
      {shard, state}
    else
      {^node, region} = List.keyfind(state.regions, node, 0)
      new = GenServer.call(region, {:grow, state.grow_by_node[node]}, 30_000)
      rank = Map.new(Enum.with_index(state.regions), fn {{n, _}, i} -> {n, i} end)
      all = Enum.sort_by(Tuple.to_list(state.shards) ++ new, &rank[node(&1)])
      load = Enum.reduce(new, state.load, &Map.put(&2, &1, 0))
      {hd(new), %{state | shards: List.to_tuple(all), load: load}}
    end
  end

  defp pick_shard(state, _pose) do
    shards = Tuple.to_list(state.shards)
    shard = Enum.min_by(shards, &state.load[&1])

    if state.load[shard] < state.per_shard do
      {shard, state}
    else
      opts = Keyword.put(state.shard_opts, :world, state.world)

      new =
        for _ <- 1..state.grow_by do
          {:ok, pid} = Shard.start_link(opts)
          pid
        end

      load = Enum.reduce(new, state.load, &Map.put(&2, &1, 0))
      {hd(new), %{state | shards: List.to_tuple(shards ++ new), load: load}}
    end
  end

  # how far from its centre a robot's sensors, moves and contacts can
  # touch another body: a region holds the ghosts within this of its robots
  defp reach(description) do
    sensors =
      for s <- description.sensors do
        {px, py, _} = Map.get(s, :pose) || {0.0, 0.0, 0.0}
        range = with {_min, max} <- Map.get(s, :range), do: max
        (range || 0.0) + :math.sqrt(px * px + py * py) + (Map.get(s, :ring_radius) || 0.0)
      end

    Enum.max([0.0 | sensors]) + 2 * description.footprint.radius + @ghost_slack
  end

  defp take_index(%{free_indexes: [index | rest]} = state),
    do: {index, %{state | free_indexes: rest}}

  defp take_index(state), do: {state.next_index, %{state | next_index: state.next_index + 1}}
end
