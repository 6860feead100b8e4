Code.require_file("support/nav_run.exs", __DIR__)

defmodule ThinkingCap.Bench.Explore do
  @moduledoc """
  `mix tc.bench explore [--map PATH.yaml ...] [--runs N] [--seed S]`:
  exploring an unknown building. In each `map_server` map (default: the
  office drawn in `priv/maps/office.yaml` and nav2's `turtlebot3_world`),
  each run starts the office robot (no beacon sensor) at a random
  reachable pose with an empty WDF: the map builder starts from nothing,
  the laser localizer holds the robot to the map being built (SLAM), and
  the planner explores (`task: :explore`) until no frontier is left
  reachable, then saves the map; at most 30 simulated minutes.

  Figures, from the saved map (`map_server` format, read back):
  `coverage_pct`, the share of the true free cells reachable from the
  start that it labels free; `accuracy_pct`, the share of its labelled
  cells (free or occupied) whose label the true map has within 5 cm;
  `seconds`, the simulated time taken (mean).

  Ends with `explore: runs=N coverage_pct=C accuracy_pct=A seconds=S`.

  For tuning: `TC_TRACE=1` prints the estimate's error every second
  (every 0.1 s in the first 10 s) with the command, the active
  behaviours, the plan's state, the frontier aimed at (`tgt`), how many
  were given up (`gu`) and the way left (`togo`, m); every 100 s the
  coverage of the map built so far; and at the end the map builder's pose
  graph against where the robot truly was (the nodes' mean error, 25
  at a time, and what remains after the best rigid fit); `TC_LIMIT` cuts runs short (s);
  `TC_MCL`, `TC_MAPPER` and `TC_PLANNER` hold keyword
  lists (Elixir terms) added to the localizer's, the map builder's and
  the planner's params (`TC_PLANNER='[area_gain: 0.0]'`); `TC_KEEP=1` keeps the saved maps; `TC_DUMP=path` (with
  `TC_TRACE`) writes the final pose graph and where its nodes truly were
  (`:erlang.term_to_binary/1` of `%{nodes:, truth:, edges:, along:}`);
  `TC_IDEAL_ODOM=1` takes the systematic odometry errors (wheel
  diameters, wheelbase) out of the simulated robot, leaving its slips.
  """

  alias ThinkingCap.Bench.NavRun
  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Tuples
  require Tuples
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @limit 1800.0
  @root Path.expand("..", __DIR__)

  def run(args) do
    {opts, _, _} = OptionParser.parse(args, strict: [map: :keep, runs: :integer, seed: :integer])

    maps =
      case Keyword.get_values(opts, :map) do
        [] ->
          Enum.map(
            ["priv/maps/office.yaml", "priv/maps/turtlebot3_world.yaml"],
            &Path.join(@root, &1)
          )

        given ->
          Enum.map(given, &Path.expand/1)
      end

    runs = opts[:runs] || 3
    seed = opts[:seed] || 1
    tmp = NavRun.tmp_dir()
    rdf = write_rdf(tmp)
    {:ok, d} = Description.load(rdf)
    empty = Path.join(tmp, "empty.wdf")
    File.write!(empty, ~s([name: "nothing known"]))

    results =
      Enum.flat_map(maps, fn yaml ->
        name = Path.basename(yaml, ".yaml")
        world = Path.join(tmp, "#{name}.wdf")
        File.write!(world, inspect(name: name, map: [yaml: yaml]))
        {:ok, truth} = RosMap.load(yaml)
        {grid, _} = NavRun.grids(world, d.footprint.radius)
        {:ok, simworld} = Sim.World.load(world)

        free? = fn cell ->
          Sim.World.free?(simworld, Grid.centre(grid, cell), d.footprint.radius + 0.1)
        end

        rng = :rand.seed_s(:exsss, {seed, 45, 1})

        {rs, _} =
          Enum.map_reduce(1..runs, rng, fn i, rng ->
            {start, rng} = start(grid, free?, rng)
            saved = Path.join(tmp, "#{name}_#{i}.yaml")
            r = one_run(world, empty, rdf, start, saved, truth, seed * 1000 + i)
            IO.puts(line(name, i, r))
            {r, rng}
          end)

        print(name, rs)
        rs
      end)

    print("explore", results)
    if System.get_env("TC_KEEP"), do: IO.puts("kept #{tmp}"), else: File.rm_rf!(tmp)
  end

  defp write_rdf(dir) do
    {:ok, data, _} = ThinkingCap.Config.Literal.parse(File.read!(NavRun.rdf()), NavRun.rdf())
    sensors = Enum.reject(data[:sensors], &(&1[:type] == :beacon_laser))

    data =
      if System.get_env("TC_IDEAL_ODOM"),
        do:
          Keyword.update!(
            data,
            :odometry_error,
            &Keyword.merge(&1, wheel_diameter_ratio: 1.0, wheelbase_ratio: 1.0)
          ),
        else: data

    path = Path.join(dir, "no_beacons.rdf")
    File.write!(path, inspect(Keyword.put(data, :sensors, sensors), limit: :infinity))
    path
  end

  defp start(grid, free?, rng) do
    {cell, rng} = NavRun.free_cell(grid, rng)
    {th, rng} = :rand.uniform_s(rng)

    if free?.(cell) do
      {Tuple.append(Grid.centre(grid, cell), (th - 0.5) * 2 * :math.pi()), rng}
    else
      start(grid, free?, rng)
    end
  end

  defp one_run(world, empty, rdf, {sx, sy, _} = start, saved, truth, seed) do
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false, step: 0.05, seed: seed)
    {w, h} = {truth.width * truth.resolution, truth.height * truth.resolution}
    size = min(2 * max(w, h) + 4, 120.0)

    modules = [
      perception: {ThinkingCap.Perception.Fuser, []},
      localization:
        {ThinkingCap.Navigation.MCL,
         [initial: start, initial_sigma: {0.05, 0.02}, seed: seed] ++
           NavRun.env_params("TC_MCL")},
      mapper:
        {ThinkingCap.Navigation.Mapper,
         [initial: {sx, sy}, size: {size, size}] ++ NavRun.env_params("TC_MAPPER")},
      control: {ThinkingCap.Control.Blender, [], period: 0.1},
      planner:
        {ThinkingCap.Planner.Monitor,
         [task: :explore, save_to: saved, clearance: 0.35] ++ NavRun.env_params("TC_PLANNER"),
         period: 0.5}
    ]

    :ok =
      Sim.add_robot(sim, :explorer,
        rdf: rdf,
        at: start,
        controller: {Sim.LockstepController, modules: modules, rdf: rdf, wdf: empty}
      )

    Process.put(:node_truth, %{})
    Process.put(:truth, {truth, {sx, sy}})
    {time, state} = drive(sim, 0.0)
    if System.get_env("TC_TRACE"), do: node_report(sim)
    blocked = Sim.status(sim).blocked
    unless File.exists?(saved), do: save_unfinished(sim, saved)
    GenServer.stop(sim)

    {coverage, accuracy} =
      case OccupancyGrid.load(saved) do
        {:ok, map} -> score(map, truth, {sx, sy})
        {:error, _} -> {0.0, 0.0}
      end

    %{time: time, state: state, coverage: coverage, accuracy: accuracy, blocked: blocked}
  end

  # a run cut short by the time limit is scored on the map built so far
  defp save_unfinished(sim, path) do
    {:ok, c} = Sim.controller_state(sim, :explorer)
    mapper = Lockstep.state(c.lock, :mapper)

    :ok =
      mapper.grid
      |> ThinkingCap.Navigation.Maps.SensedGrid.occupancy()
      |> OccupancyGrid.crisp()
      |> OccupancyGrid.save(path)
  end

  # 10 s at a time until the exploration is done (or gave up) or time is up
  defp drive(sim, t) do
    :ok = trace_or_run(sim, t)
    t = t + 10.0
    {:ok, c} = Sim.controller_state(sim, :explorer)
    saved = Lockstep.latest(c.lock, Tuples.map_saved(:explorer))
    if System.get_env("TC_TRACE") && rem(round(t), 100) == 0, do: coverage_so_far(c.lock, t)

    limit = min(@limit, limit())

    case Lockstep.latest(c.lock, Tuples.plan(:explorer)) do
      Tuples.plan(_, %{state: s}) when s in [:done, :failed] and saved != nil -> {t, s}
      Tuples.plan(_, %{state: s}) when t >= limit -> {t, s}
      _ -> drive(sim, t)
    end
  end

  # TC_TRACE: the coverage of the map built so far, every 100 s
  defp coverage_so_far(lock, t) do
    {truth, start} = Process.get(:truth)
    grid = Lockstep.state(lock, :mapper).grid
    map = ThinkingCap.Navigation.Maps.SensedGrid.occupancy(grid)
    IO.puts("coverage at #{round(t)} s: #{NavRun.fmt(coverage(map, truth, start))} %")
  end

  defp limit, do: String.to_integer(System.get_env("TC_LIMIT") || "1800")

  # TC_TRACE=1: the true pose and the estimate every second
  defp trace_or_run(sim, t) do
    if System.get_env("TC_TRACE") do
      dt = if t < 10, do: 0.1, else: 1.0

      Enum.each(1..round(10 / dt), fn i ->
        :ok = Sim.run_for(sim, dt)
        {:ok, {x, y, th}} = Sim.pose(sim, :explorer)
        {:ok, c} = Sim.controller_state(sim, :explorer)
        note_node(c.lock, {x, y, th})

        case Lockstep.latest(c.lock, Tuples.pose(:explorer)) do
          Tuples.pose(_, %{pose: {ex, ey, eth}} = p) ->
            e = :math.sqrt((ex - x) ** 2 + (ey - y) ** 2)
            dth = normalize_angle(eth - th)

            IO.puts(
              "    t=#{NavRun.fmt(t + i * dt)} x=#{NavRun.fmt(x)} y=#{NavRun.fmt(y)} th=#{NavRun.fmt(th)} err=#{NavRun.fmt(e)} dth=#{NavRun.fmt(dth)} " <>
                "#{p[:status]} conf=#{NavRun.fmt(p[:confidence] || 0.0)}" <> control(c.lock)
            )

          _ ->
            :ok
        end
      end)
    else
      Sim.run_for(sim, 10.0)
    end
  end

  defp note_node(lock, truth) do
    case Lockstep.state(lock, :mapper) do
      %{loops: %{graph: g}} when g.next > 0 ->
        id = g.next - 1
        m = Process.get(:node_truth)
        # where the node truly was: the truth moved by the node's place
        # seen from the current odometry reading (or, without one, from
        # the current estimate: published up to 0.1 s before, a tenth of
        # a radian off in a turn)
        with false <- Map.has_key?(m, id),
             Tuples.pose(_, %{pose: est}) <- Lockstep.latest(lock, Tuples.pose(:explorer)) do
          at =
            case {g.odometry[id], Lockstep.latest(lock, Tuples.reading(:odom, :explorer))} do
              {{_, _, _} = at_node, Tuples.reading(_, _, %{pose: {_, _, _} = now})} ->
                ThinkingCap.Navigation.EKF.motion(
                  truth,
                  ThinkingCap.Navigation.EKF.relative(now, at_node)
                )

              _ ->
                ThinkingCap.Navigation.EKF.motion(
                  truth,
                  ThinkingCap.Navigation.EKF.relative(est, g.nodes[id])
                )
            end

          Process.put(:node_truth, Map.put(m, id, at))
        end

      _ ->
        :ok
    end
  end

  # the final graph's nodes against where the robot truly was (TC_TRACE)
  defp node_report(sim) do
    {:ok, c} = Sim.controller_state(sim, :explorer)

    with %{loops: %{graph: g}} <- Lockstep.state(c.lock, :mapper),
         truth = Process.get(:node_truth),
         [_ | _] <- for({id, t} <- truth, Map.has_key?(g.nodes, id), do: {id, g.nodes[id], t}) do
      report_nodes(g, truth)
    else
      _ -> :ok
    end
  end

  defp report_nodes(g, truth) do
    pairs = for {id, t} <- truth, Map.has_key?(g.nodes, id), do: {id, g.nodes[id], t}

    if path = System.get_env("TC_DUMP"),
      do:
        File.write!(
          path,
          :erlang.term_to_binary(%{nodes: g.nodes, truth: truth, edges: g.edges, along: g.along})
        )

    loops = Enum.count(g.edges, &(&1.kind == :loop))
    IO.puts("nodes: #{g.next} loops edges: #{loops}")

    pairs
    |> Enum.sort()
    |> Enum.chunk_every(25)
    |> Enum.each(fn chunk ->
      errs =
        for {_, {x, y, th}, {tx, ty, tth}} <- chunk,
            do: {:math.sqrt((x - tx) ** 2 + (y - ty) ** 2), normalize_angle(th - tth)}

      {id0, _, {tx, ty, _}} = hd(chunk)
      n = length(errs)

      IO.puts(
        "  node #{id0} at (#{NavRun.fmt(tx)}, #{NavRun.fmt(ty)}): err #{NavRun.fmt(Enum.sum(Enum.map(errs, &elem(&1, 0))) / n)} dth #{NavRun.fmt(Enum.sum(Enum.map(errs, &elem(&1, 1))) / n)}"
      )
    end)

    # best rigid fit of node positions onto truth
    n = length(pairs)

    {mx, my, tx, ty} =
      Enum.reduce(pairs, {0.0, 0.0, 0.0, 0.0}, fn {_, {x, y, _}, {a, b, _}}, {s1, s2, s3, s4} ->
        {s1 + x / n, s2 + y / n, s3 + a / n, s4 + b / n}
      end)

    {sc, ss} =
      Enum.reduce(pairs, {0.0, 0.0}, fn {_, {x, y, _}, {a, b, _}}, {sc, ss} ->
        {px, py, qx, qy} = {x - mx, y - my, a - tx, b - ty}
        {sc + px * qx + py * qy, ss + px * qy - py * qx}
      end)

    rot = :math.atan2(ss, sc)

    res =
      for {_, {x, y, _}, {a, b, _}} <- pairs do
        {px, py} = {x - mx, y - my}

        {rx, ry} =
          {:math.cos(rot) * px - :math.sin(rot) * py + tx,
           :math.sin(rot) * px + :math.cos(rot) * py + ty}

        :math.sqrt((rx - a) ** 2 + (ry - b) ** 2)
      end

    raw = for {_, {x, y, _}, {a, b, _}} <- pairs, do: :math.sqrt((x - a) ** 2 + (y - b) ** 2)

    IO.puts(
      "fit: rotation #{NavRun.fmt(rot)} rad, centroids (#{NavRun.fmt(tx - mx)}, #{NavRun.fmt(ty - my)}) m apart; mean err raw #{NavRun.fmt(Enum.sum(raw) / n)} after fit #{NavRun.fmt(Enum.sum(res) / n)} max after #{NavRun.fmt(Enum.max(res))}"
    )
  end

  # what the controller drove and which behaviours were active
  defp control(lock) do
    command =
      case Lockstep.latest(lock, Tuples.drive(:explorer)) do
        Tuples.drive(_, %{command: {:velocity, v, w}}) -> " v=#{NavRun.fmt(v)} w=#{NavRun.fmt(w)}"
        _ -> ""
      end

    active =
      case Lockstep.latest(lock, Tuples.activation(:explorer)) do
        Tuples.activation(_, a) when is_map(a) ->
          a
          |> Enum.filter(fn {_, d} -> d > 0.05 end)
          |> Enum.map_join(",", fn {b, d} -> "#{b}:#{NavRun.fmt(d)}" end)

        _ ->
          ""
      end

    command <> " act=" <> active <> plan(lock)
  end

  defp togo([_, _ | _] = path) do
    path
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.reduce(0.0, fn [{ax, ay}, {bx, by}], l ->
      l + :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
    end)
    |> NavRun.fmt()
  end

  defp togo(_path), do: "0.00"

  # the frontier aimed at, the plan's state and how many were given up
  defp plan(lock) do
    case Lockstep.latest(lock, Tuples.plan(:explorer)) do
      Tuples.plan(_, %{state: s, waypoint: {gx, gy}, given_up: g} = p) ->
        " st=#{s} tgt=(#{NavRun.fmt(gx)},#{NavRun.fmt(gy)}) gu=#{length(g)} togo=#{togo(p[:path])}"

      Tuples.plan(_, %{state: s, given_up: g}) ->
        " st=#{s} gu=#{length(g)}"

      _ ->
        ""
    end
  end

  ## scoring

  defp score(%OccupancyGrid{} = map, truth, start) do
    {coverage(map, truth, start), accuracy(map, truth)}
  end

  # the true free cells reachable from the start (4-connected), and how
  # many of them the map labels free
  defp coverage(map, truth, {sx, sy}) do
    {ox, oy, _} = truth.origin
    res = truth.resolution
    start = {floor((sx - ox) / res), floor((sy - oy) / res)}
    reachable = flood(truth, start)

    seen =
      Enum.count(reachable, fn {c, r} ->
        OccupancyGrid.value(
          map,
          OccupancyGrid.cell_of(map, {ox + (c + 0.5) * res, oy + (r + 0.5) * res})
        ) == 0
      end)

    100.0 * seen / max(length(reachable), 1)
  end

  defp flood(truth, start) do
    w = truth.width
    visited = :atomics.new(truth.width * truth.height, [])

    free? = fn {c, r} ->
      c >= 0 and r >= 0 and c < w and r < truth.height and RosMap.cell(truth, c, r) == 0
    end

    if free?.(start) do
      :atomics.put(visited, index(start, w) + 1, 1)
      bfs(:queue.from_list([start]), [start], visited, w, free?)
    else
      []
    end
  end

  defp bfs(queue, acc, visited, w, free?) do
    case :queue.out(queue) do
      {:empty, _} ->
        acc

      {{:value, {c, r}}, queue} ->
        {queue, acc} =
          Enum.reduce([{c + 1, r}, {c - 1, r}, {c, r + 1}, {c, r - 1}], {queue, acc}, fn n,
                                                                                         {q, a} ->
            if free?.(n) and :atomics.compare_exchange(visited, index(n, w) + 1, 0, 1) == :ok,
              do: {:queue.in(n, q), [n | a]},
              else: {q, a}
          end)

        bfs(queue, acc, visited, w, free?)
    end
  end

  defp index({c, r}, w), do: r * w + c

  # the map's labelled cells whose label the truth has within 5 cm
  defp accuracy(map, truth) do
    {ox, oy, _} = truth.origin
    tres = truth.resolution
    k = max(1, ceil(0.05 / tres - 1.0e-9))
    {mx, my} = map.origin

    {ok, all} =
      for r <- 0..(map.height - 1), c <- 0..(map.width - 1), reduce: {0, 0} do
        {ok, all} ->
          v = OccupancyGrid.value(map, {c, r})

          if v < 0 do
            {ok, all}
          else
            label = if v >= 50, do: 100, else: 0
            x = mx + (c + 0.5) * map.resolution
            y = my + (r + 0.5) * map.resolution
            {tc, tr} = {floor((x - ox) / tres), floor((y - oy) / tres)}

            good =
              Enum.any?(for(dc <- -k..k, dr <- -k..k, do: {tc + dc, tr + dr}), fn {a, b} ->
                a >= 0 and b >= 0 and a < truth.width and b < truth.height and
                  RosMap.cell(truth, a, b) == label
              end)

            {if(good, do: ok + 1, else: ok), all + 1}
          end
      end

    100.0 * ok / max(all, 1)
  end

  defp line(name, i, r) do
    "  #{name} #{i}: #{r.state} in #{NavRun.fmt(r.time)} s, coverage #{NavRun.fmt(r.coverage)} %, " <>
      "accuracy #{NavRun.fmt(r.accuracy)} %, blocked #{r.blocked}"
  end

  defp print(label, rs) do
    IO.puts(
      "#{label}: runs=#{length(rs)} coverage_pct=#{NavRun.fmt(NavRun.mean(Enum.map(rs, & &1.coverage)))} " <>
        "accuracy_pct=#{NavRun.fmt(NavRun.mean(Enum.map(rs, & &1.accuracy)))} " <>
        "seconds=#{NavRun.fmt(NavRun.mean(Enum.map(rs, & &1.time)))}"
    )
  end
end
