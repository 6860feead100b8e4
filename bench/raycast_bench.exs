defmodule ThinkingCap.Bench.Raycast do
  @moduledoc """
  `mix tc.bench raycast`: rays per second of `ThinkingCap.Sim.Raycast.scan/5`
  in the 30 m × 50 m warehouse map (`priv/maps/warehouse.yaml`),
  with the simulator benchmark's sensor set per robot: a 180-beam laser
  (180°, 8 m, no reflections; one group per beam) and 16 sonars (15° cone,
  5 m, 3 rays each, max_bounces 2, critical angle 0.26 rad, one crosstalk
  ring) — 196 groups, 228 rays per scan. 100 robots (bodies of radius 0.25 m) stand at random free
  poses; each scan is at one of them, excluding its own body.

  Figures: one process (one core) and one process per scheduler; rays/s
  count the 228 primary rays of a scan (bounces not counted).

      mix tc.bench raycast [seconds_per_run]
  """

  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Sim.Raycast

  @robots 100
  @radius 0.25

  def run(args) do
    seconds =
      case args do
        [s | _] -> String.to_integer(s)
        [] -> 3
      end

    map_path = Path.expand("priv/maps/warehouse.yaml", root())
    {:ok, map} = RosMap.load(map_path)
    {t_new, {:ok, world}} = :timer.tc(fn -> Raycast.new(grid: map) end)

    IO.puts(
      "ThinkingCap ray-casting benchmark (#{System.schedulers_online()} schedulers, OTP #{System.otp_release()})"
    )

    IO.puts(
      "map #{map.width}x#{map.height} cells at #{map.resolution} m; new/1 (distance transform) #{div(t_new, 1000)} ms"
    )

    :rand.seed(:exsss, {1, 2, 3})
    poses = free_poses(world, map, @robots)
    :ok = Raycast.set_bodies(world, for({x, y, _} <- poses, do: {x, y, @radius}))
    groups = Raycast.pack_groups(sensors())
    rays_per_scan = Enum.sum(for g <- sensors(), do: Map.get(g, :rays, 1))
    poses = List.to_tuple(poses)

    # warm up
    _ = scans(world, groups, poses, 2_000)

    {n1, us1} = timed(world, groups, poses, seconds)
    single = n1 * rays_per_scan / (us1 / 1.0e6)
    us_per_scan = us1 / n1

    IO.puts(
      "1 process: #{n1} scans in #{Float.round(us1 / 1.0e6, 2)} s: #{Float.round(us_per_scan, 2)} µs/scan, #{round(single)} rays/s"
    )

    procs = System.schedulers_online()

    results =
      1..procs
      |> Enum.map(fn _ -> Task.async(fn -> timed(world, groups, poses, seconds) end) end)
      |> Enum.map(&Task.await(&1, :infinity))

    total = Enum.sum(for {n, us} <- results, do: n * rays_per_scan / (us / 1.0e6))

    IO.puts(
      "#{procs} processes: #{round(total)} rays/s in total (#{round(total / procs)} per process)"
    )

    laser_only = Raycast.pack_groups(laser())
    {nl, usl} = timed(world, laser_only, poses, seconds)

    IO.puts(
      "laser alone (180 rays): #{Float.round(usl / nl, 2)} µs/scan, #{round(nl * 180 / (usl / 1.0e6))} rays/s"
    )

    sonars = Raycast.pack_groups(sonars())
    {ns, uss} = timed(world, sonars, poses, seconds)

    IO.puts(
      "16 sonars alone (48 rays): #{Float.round(uss / ns, 2)} µs/scan, #{round(ns * 48 / (uss / 1.0e6))} rays/s"
    )

    IO.puts(
      "raycast: rays_per_s=#{round(single)} us_per_scan=#{Float.round(us_per_scan, 2)} rays_per_s_#{procs}procs=#{round(total)}"
    )
  end

  # as the simulator packs them (ThinkingCap.Sim.Core.Sensors): one group
  # per laser beam (each beam is a reading), one per sonar
  defp sensors, do: laser() ++ sonars()

  defp laser do
    for j <- 0..179 do
      %{
        x: 0.1,
        heading: -:math.pi() / 2 + j * :math.pi() / 179,
        max_range: 8.0,
        min_range: 0.05,
        noise_std: 0.01,
        dropout: 0.001
      }
    end
  end

  defp sonars do
    for k <- 0..15 do
      a = k * 2 * :math.pi() / 16

      %{
        x: 0.2 * :math.cos(a),
        y: 0.2 * :math.sin(a),
        heading: a,
        fov: 15 * :math.pi() / 180,
        rays: 3,
        min_range: 0.02,
        max_range: 5.0,
        max_bounces: 2,
        critical_angle: 0.26,
        ring: 0,
        noise_std: 0.01,
        noise_prop: 0.01,
        dropout: 0.01
      }
    end
  end

  defp timed(world, groups, poses, seconds) do
    deadline = System.monotonic_time(:microsecond) + seconds * 1_000_000
    t0 = System.monotonic_time(:microsecond)
    n = loop(world, groups, poses, deadline, 0)
    {n, System.monotonic_time(:microsecond) - t0}
  end

  defp loop(world, groups, poses, deadline, n) do
    _ = scans(world, groups, poses, 500, n)

    if System.monotonic_time(:microsecond) < deadline,
      do: loop(world, groups, poses, deadline, n + 500),
      else: n + 500
  end

  defp scans(world, groups, poses, count, base \\ 0) do
    Enum.each(0..(count - 1), fn i ->
      k = rem(base + i, tuple_size(poses))
      {x, y, th} = elem(poses, k)
      Raycast.scan(world, {x, y, th + i * 0.01}, groups, k, base + i)
    end)
  end

  # random poses in free space with at least the body radius of clearance
  defp free_poses(world, map, n) do
    {ox, oy, _} = map.origin
    w = map.width * map.resolution
    h = map.height * map.resolution

    Stream.repeatedly(fn ->
      {ox + :rand.uniform() * w, oy + :rand.uniform() * h, :rand.uniform() * 6.283}
    end)
    |> Stream.filter(fn {x, y, _} ->
      col = trunc((x - ox) / map.resolution)
      row = trunc((y - oy) / map.resolution)

      RosMap.cell(map, min(col, map.width - 1), min(row, map.height - 1)) == 0 and
        Raycast.clearance(world, x, y, -1, 0.5) >= 0.5
    end)
    |> Enum.take(n)
  end

  defp root do
    cwd = File.cwd!()
    if File.dir?(Path.join(cwd, "apps")), do: cwd, else: Path.expand("../..", cwd)
  end
end
