defmodule ThinkingCap.Bench.NavRun do
  @moduledoc """
  What the navigation benchmarks share: a true world built from a
  `map_server` map (its occupied cells; plus boxes the robot is not told
  about, and beacons), start and goal pairs drawn from reachable free
  space, one run of the whole stack in lockstep with the simulator as
  fast as possible, and the summary figures.
  """

  alias ThinkingCap.Navigation.{AStar, Grid, Maps}
  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.LockstepController
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Tuples
  require Tuples

  @root Path.expand("../..", __DIR__)
  @default_maps ["priv/maps/turtlebot3_world.yaml", "priv/maps/warehouse.yaml"]

  @doc "Parses `--map PATH` (repeatable), `--runs N`, `--seed S`, `--trace`."
  def options(args, default_runs) do
    {opts, _, _} =
      OptionParser.parse(args,
        strict: [map: :keep, runs: :integer, seed: :integer, trace: :boolean]
      )

    maps =
      case Keyword.get_values(opts, :map) do
        [] -> Enum.map(@default_maps, &Path.join(@root, &1))
        given -> Enum.map(given, &Path.expand/1)
      end

    Process.put(:trace, opts[:trace] || false)
    %{maps: maps, runs: opts[:runs] || default_runs, seed: opts[:seed] || 1}
  end

  def rdf, do: Path.join(@root, "priv/examples/office_robot.rdf")

  @doc """
  Writes a WDF of `map_yaml` into `dir` with beacons spread over its free
  space (one per 25 m², at least 16) and `obstacles`; returns its path.
  """
  def write_wdf(dir, name, map_yaml, obstacles \\ []) do
    {:ok, map} = ThinkingCap.Config.RosMap.load(map_yaml)
    rng = :rand.seed_s(:exsss, {7, 7, 7})

    data = [
      name: name,
      map: [yaml: map_yaml],
      beacons:
        for(
          {{x, y}, i} <- Enum.with_index(beacons(map, beacon_count(map), rng)),
          do: [name: :"b#{i}", at: {x, y}]
        ),
      obstacles:
        for({polygon, i} <- Enum.with_index(obstacles), do: [name: :"box#{i}", polygon: polygon])
    ]

    path = Path.join(dir, "#{name}.wdf")
    File.write!(path, inspect(data, limit: :infinity))
    path
  end

  defp beacon_count(map) do
    free = map.data |> :binary.bin_to_list() |> Enum.count(&(&1 == 0))
    max(16, round(free * map.resolution * map.resolution / 25))
  end

  defp beacons(map, n, rng) do
    {ox, oy, _} = map.origin

    Stream.unfold(rng, fn rng ->
      {u, rng} = :rand.uniform_s(rng)
      {v, rng} = :rand.uniform_s(rng)
      {{floor(u * map.width), floor(v * map.height)}, rng}
    end)
    |> Stream.filter(fn {c, r} -> ThinkingCap.Config.RosMap.cell(map, c, r) == 0 end)
    |> Stream.map(fn {c, r} ->
      {ox + (c + 0.5) * map.resolution, oy + (r + 0.5) * map.resolution}
    end)
    |> Enum.take(n)
  end

  @doc """
  The grids of a world for a robot of `radius`: the planner's (inflated by
  the radius and the planner's margin) and the tight one (the radius
  alone: the shortest collision-free way a robot of this size could take).
  """
  def grids(wdf_path, radius) do
    wdf = ThinkingCap.Config.read!(wdf_path)
    map = Maps.grid_from_wdf(wdf, [])
    {Maps.inflate(map, radius + 0.08), Maps.inflate(map, radius)}
  end

  @doc """
  `n` start and goal pairs reachable on `grid`, the path at least 2 m
  long, each `{start_pose, goal_point, optimal_m}` with the optimal length
  on `tight`; drawn with `rng`.
  """
  def pairs(grid, tight, free?, n, rng), do: pairs(grid, tight, free?, n, rng, [])

  defp pairs(_grid, _tight, _free?, 0, rng, acc), do: {Enum.reverse(acc), rng}

  defp pairs(grid, tight, free?, n, rng, acc) do
    {a, rng} = free_cell(grid, rng)
    {b, rng} = free_cell(grid, rng)

    with true <- free?.(a) and free?.(b),
         {:ok, %{cost: cost}} when cost * grid.resolution >= 2.0 <- AStar.plan(grid, a, b),
         {:ok, %{cost: optimal, path: path}} <- AStar.plan(tight, a, b) do
      {th, rng} = :rand.uniform_s(rng)
      start = Grid.centre(grid, a) |> Tuple.append((th - 0.5) * 2 * :math.pi())

      pair = %{
        start: start,
        goal: Grid.centre(grid, b),
        optimal: optimal * tight.resolution,
        path: Enum.map(path, &Grid.centre(tight, &1))
      }

      pairs(grid, tight, free?, n - 1, rng, [pair | acc])
    else
      _ -> pairs(grid, tight, free?, n, rng, acc)
    end
  end

  def free_cell(grid, rng) do
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    cell = {floor(u * grid.width), floor(v * grid.height)}
    if Grid.passable?(grid, cell), do: {cell, rng}, else: free_cell(grid, rng)
  end

  @doc """
  One run: the robot of `rdf` at `pair.start` in the simulated `world`
  (a WDF path: the truth), its modules told `robot_wdf`, sent to
  `pair.goal`. Returns success, time, driven length, collisions and the
  planner's replans.
  """
  def run(world, robot_wdf, pair, opts) do
    seed = Keyword.fetch!(opts, :seed)
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false, step: 0.05, seed: seed)
    {sx, sy, sth} = pair.start
    goal = pair.goal

    modules = Keyword.fetch!(opts, :modules).(pair)
    rdf = Keyword.get(opts, :rdf, rdf())

    :ok =
      Sim.add_robot(sim, :nav,
        rdf: rdf,
        at: {sx, sy, sth},
        controller: {LockstepController, modules: modules, rdf: rdf, wdf: robot_wdf}
      )

    for walker <- Keyword.get(opts, :walkers, []),
        do: :ok = apply(Sim, :add_walker, [sim | walker])

    limit = pair.optimal / 0.2 * 3 + 30
    acc = %{driven: 0.0, last: {sx, sy}, replans: %{}, track: []}

    acc =
      if d = System.get_env("TC_DRAW"),
        do: Map.put(acc, :draw_ctx, {d, world, pair, seed}),
        else: acc

    {time, acc} = drive(sim, limit, acc, 0)

    if dir = System.get_env("TC_DRAW") do
      {:ok, cs} = Sim.controller_state(sim, :nav)
      m = Lockstep.latest(cs.lock, Tuples.map(:nav))
      p = Lockstep.latest(cs.lock, Tuples.plan(:nav))

      draw(dir, world, pair, acc.track, seed, m && elem(m, 2), [
        {(p && elem(p, 2).path) || [], {200, 0, 200}}
      ])
    end

    status = Sim.status(sim)
    {:ok, cstate} = Sim.controller_state(sim, :nav)
    plan = Lockstep.latest(cstate.lock, Tuples.plan(:nav))
    estimate = Lockstep.latest(cstate.lock, Tuples.pose(:nav))
    GenServer.stop(sim)
    {gx, gy} = goal
    {lx, ly} = acc.last
    gap = :math.sqrt((lx - gx) ** 2 + (ly - gy) ** 2)
    state = if plan, do: elem(plan, 2).state

    %{
      success: state == :done and gap <= 0.5,
      state: state,
      reason: plan && elem(plan, 2)[:reason],
      gap: gap,
      pose_error: pose_error(estimate, acc.last),
      time: time,
      # the planner stops within its tolerance of the goal: the rest of the
      # way counts as driven, so that stopping short does not look shorter
      driven: acc.driven + gap,
      optimal: pair.optimal,
      blocked: status.blocked,
      replans: Map.values(acc.replans)
    }
  end

  defp pose_error(Tuples.pose(_, %{pose: {ex, ey, _}}), {x, y}),
    do: :math.sqrt((ex - x) ** 2 + (ey - y) ** 2)

  defp pose_error(_estimate, _true), do: nil

  # 0.1 s at a time, summing the true pose's steps and keeping every plan
  # the planner made, until the plan is done or failed or time is up
  defp drive(sim, limit, acc, step) do
    :ok = Sim.run_for(sim, 0.1)
    {:ok, {x, y, _}} = Sim.pose(sim, :nav)
    {lx, ly} = acc.last
    acc = %{acc | driven: acc.driven + :math.sqrt((x - lx) ** 2 + (y - ly) ** 2), last: {x, y}}
    acc = %{acc | track: [{x, y} | acc.track]}
    time = Sim.time(sim)
    {:ok, cstate} = Sim.controller_state(sim, :nav)
    plan = Lockstep.latest(cstate.lock, Tuples.plan(:nav))
    acc = flip_frame(acc, cstate, time, plan)

    acc =
      case plan do
        Tuples.plan(_, %{planning: %{} = p, planned_at: at}) when at != nil ->
          %{acc | replans: Map.put(acc.replans, at, p)}

        _ ->
          acc
      end

    if Process.get(:trace) == true and rem(step, 5) == 0,
      do: trace(time, {x, y}, plan, cstate.lock, Sim.walker_discs(sim))

    case plan do
      Tuples.plan(_, %{state: s}) when s in [:done, :failed] -> {time, acc}
      _ when time >= limit -> {time, acc}
      _ -> drive(sim, limit, acc, step + 1)
    end
  end

  defp trace(time, {x, y}, plan, lock, walkers) do
    activation =
      case Lockstep.latest(lock, Tuples.activation(:nav)) do
        Tuples.activation(_, a) -> for {b, v} <- a, v >= 0.05, do: "#{b}=#{fmt(v)}"
        nil -> []
      end

    Tuples.drive(_, %{command: command}) =
      Lockstep.latest(lock, Tuples.drive(:nav)) || Tuples.drive(nil, %{command: nil})

    state =
      case plan do
        Tuples.plan(_, %{state: st, path: path, replans: n}) ->
          "#{st} path=#{fmt(path_length(path || []))} replans=#{n}"

        _ ->
          nil
      end

    estimate =
      case Lockstep.latest(lock, Tuples.pose(:nav)) do
        Tuples.pose(_, %{pose: {ex, ey, _}, status: status}) ->
          " estimate (#{fmt(ex)}, #{fmt(ey)}) #{status}"

        _ ->
          ""
      end

    people = for {wx, wy, _r} <- walkers, do: " person (#{fmt(wx)}, #{fmt(wy)})"

    IO.puts(
      "    t=#{fmt(time)} (#{fmt(x)}, #{fmt(y)})#{estimate} #{state} #{inspect(command)} " <>
        Enum.join(activation, " ") <> Enum.join(people)
    )
  end

  # TC_DRAW=DIR: the true world (black), the optimal path (blue), the
  # path driven (red, its start green) as DIR/run_SEED.png, 2 cm a pixel
  defp path_length(path) do
    path
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.map(fn [{a, b}, {c, d}] -> :math.sqrt((c - a) ** 2 + (d - b) ** 2) end)
    |> Enum.sum()
  end

  # TC_DRAW: a frame each time the plan's length jumps by 0.9 m or more
  defp flip_frame(%{draw_ctx: {dir, world, pair, seed}} = acc, cstate, time, plan) do
    path = (plan && elem(plan, 2).path) || []
    len = path_length(path)

    old = Map.get(acc, :old_plan, {[], len})

    if abs(len - elem(old, 1)) >= 0.9 and elem(old, 0) != [] do
      m = Lockstep.latest(cstate.lock, Tuples.map(:nav))

      draw(dir, world, pair, acc.track, "#{seed}_t#{round(time * 10)}", m && elem(m, 2), [
        {elem(old, 0), {200, 0, 200}},
        {path, {0, 220, 0}}
      ])
    end

    Map.put(acc, :old_plan, {path, len})
  end

  defp flip_frame(acc, _cstate, _time, _plan), do: acc

  defp draw(dir, world, pair, track, seed, map, plan) do
    {:ok, w} = Sim.World.load(world)
    {xs, ys} = Enum.unzip(track ++ pair.path)

    {x0, x1, y0, y1} =
      case System.get_env("TC_DRAW_WINDOW") do
        nil -> {Enum.min(xs) - 1.5, Enum.max(xs) + 1.5, Enum.min(ys) - 1.5, Enum.max(ys) + 1.5}
        w -> w |> String.split(",") |> Enum.map(&String.to_float/1) |> List.to_tuple()
      end

    res = if System.get_env("TC_DRAW_WINDOW"), do: 0.005, else: 0.01
    {cols, rows} = {ceil((x1 - x0) / res), ceil((y1 - y0) / res)}
    px = fn {x, y} -> {floor((x - x0) / res), rows - 1 - floor((y - y0) / res)} end

    marks =
      Map.new(
        Enum.map(pair.path, &{px.(&1), {0, 0, 255}}) ++
          Enum.map(Map.get(pair, :true_path, []), &{px.(&1), {0, 160, 160}}) ++
          Enum.map(track, &{px.(&1), {255, 0, 0}}) ++
          Enum.flat_map(plan, fn {pts, colour} ->
            for pt <- densify(pts),
                {c, r} = px.(pt),
                dc <- -1..1,
                dr <- -1..1,
                do: {{c + dc, r + dr}, colour}
          end) ++
          [{px.(List.last(track)), {0, 200, 0}}, {px.(pair.goal), {255, 0, 255}}]
      )

    pixels =
      for r <- 0..(rows - 1), c <- 0..(cols - 1), into: <<>> do
        case Map.get(marks, {c, r}) do
          {a, b, d} ->
            <<a, b, d>>

          nil ->
            p = {x0 + (c + 0.5) * res, y0 + (rows - 1 - r + 0.5) * res}

            sensed =
              map &&
                ThinkingCap.Navigation.OccupancyGrid.value(
                  map,
                  ThinkingCap.Navigation.OccupancyGrid.cell_of(map, p)
                )

            cond do
              not Sim.World.free?(w, p, 0.0) and sensed != nil and sensed >= 50 -> <<90, 40, 0>>
              not Sim.World.free?(w, p, 0.0) -> <<0, 0, 0>>
              sensed != nil and sensed >= 50 -> <<255, 150, 0>>
              not Sim.World.known_free?(w, p) -> <<120, 120, 120>>
              true -> <<255, 255, 255>>
            end
        end
      end

    File.mkdir_p!(dir)
    File.write!(Path.join(dir, "run_#{seed}.png"), png(cols, rows, pixels))
  end

  defp densify([a, b | rest]) do
    {ax, ay} = a
    {bx, by} = b
    n = max(1, ceil(:math.sqrt((bx - ax) ** 2 + (by - ay) ** 2) / 0.01))

    for(i <- 0..(n - 1), do: {ax + (bx - ax) * i / n, ay + (by - ay) * i / n}) ++
      densify([b | rest])
  end

  defp densify(pts), do: pts

  defp png(cols, rows, rgb) do
    raw =
      for r <- 0..(rows - 1),
          into: <<>>,
          do: <<0, binary_part(rgb, r * cols * 3, cols * 3)::binary>>

    chunk = fn type, data ->
      <<byte_size(data)::32, type::binary, data::binary, :erlang.crc32(type <> data)::32>>
    end

    <<137, 80, 78, 71, 13, 10, 26, 10>> <>
      chunk.("IHDR", <<cols::32, rows::32, 8, 2, 0, 0, 0>>) <>
      chunk.("IDAT", :zlib.compress(raw)) <> chunk.("IEND", <<>>)
  end

  @doc "One line for a run."
  def line(label, i, r) do
    "  #{label} #{i}: #{if r.success, do: "ok  ", else: "FAIL"} #{fmt(r.time)} s, " <>
      "driven #{fmt(r.driven)} m / optimal #{fmt(r.optimal)} m, blocked #{r.blocked}" <>
      if(r.success,
        do: "",
        else:
          " (plan #{r.state}#{if r.reason, do: ": " <> r.reason}, #{fmt(r.gap)} m from the goal, " <>
            "localization off by #{if r.pose_error, do: fmt(r.pose_error), else: "-"} m)"
      )
  end

  @doc "success, collisions and path ratio over runs."
  def summary(results) do
    ok = Enum.filter(results, & &1.success)

    %{
      runs: length(results),
      success: length(ok),
      collisions: Enum.count(results, &(&1.blocked > 0)),
      path_ratio: mean(Enum.map(ok, &(&1.driven / max(&1.optimal, 1.0e-6))))
    }
  end

  @doc """
  Extra params for a module, for tuning: the keyword list (an Elixir term)
  in the environment variable `name` (`TC_MCL`, `TC_MAPPER`, `TC_CONTROL`), or `[]`.
  """
  def env_params(name) do
    case System.get_env(name) do
      nil -> []
      term -> elem(Code.eval_string(term), 0)
    end
  end

  def mean([]), do: 0.0
  def mean(xs), do: Enum.sum(xs) / length(xs)

  def fmt(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)

  def tmp_dir do
    # the OS process in the name: benchmarks run side by side must not
    # share (and remove) each other's directories
    name = "tc_bench_#{System.pid()}_#{System.unique_integer([:positive])}"
    dir = Path.join(System.tmp_dir!(), name)
    File.mkdir_p!(dir)
    dir
  end
end
