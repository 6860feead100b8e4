defmodule ThinkingCap.Sim.Core.Sensors do
  @moduledoc false
  # The sensors of one simulated robot: set up once from the robot's
  # description (ray groups packed for the ray-casting NIF, rates, fault
  # draws), then read at their rates. Geometry, noise and the per-reading
  # faults (dropouts, spikes) are cast in C; the stateful faults (stuck,
  # drifting bias, dead) are applied here.

  alias ThinkingCap.Sim.Raycast
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @two_pi 2 * :math.pi()
  @ranged [:sonar, :laser]

  @doc "Sets up every sensor of a description for a step of `dt` seconds."
  def setup(sensors, dt, rng) do
    {set, rng} =
      sensors
      |> Enum.with_index()
      |> Enum.map_reduce(rng, fn {s, index}, rng -> setup_one(s, index, dt, rng) end)

    {set, rng}
  end

  defp setup_one(s, index, dt, rng) do
    groups = groups(s, index)
    {faults, rng} = draw_faults(s.faults, max(length(groups), 1), rng)
    {min_range, max_range} = s[:range] || {0.0, 0.0}

    sensor = %{
      name: s.name,
      type: s.type,
      index: index,
      every: max(1, round(1 / (s.rate * dt))),
      rays: Enum.reduce(groups, 0, &(&1.rays + &2)),
      packed: packings(groups, faults),
      min_range: min_range * 1.0,
      max_range: max_range * 1.0,
      fov: (s[:fov] || 0.0) * 1.0,
      pose: s.pose,
      noise: s.noise,
      faults: faults,
      stuck: %{},
      # a ranged sensor's payload with every key, filled in at each reading
      payload: payload_template(s, groups, min_range, max_range)
    }

    {sensor, rng}
  end

  # One ray group per reading: a sonar transducer (a cone of rays) or a
  # laser beam.
  defp groups(%{type: :sonar} = s, index) do
    {px, py, pth} = s.pose
    {min_range, max_range} = s.range

    for i <- 0..(s.count - 1) do
      heading = pth + @two_pi * i / s.count

      %{
        x: px + s.ring_radius * :math.cos(heading),
        y: py + s.ring_radius * :math.sin(heading),
        heading: heading,
        fov: s.fov,
        rays: s.rays,
        min_range: min_range,
        max_range: max_range,
        max_bounces: s.max_reflections,
        critical_angle: s.critical_angle,
        ring: if(s[:crosstalk], do: index, else: -1)
      }
      |> Map.merge(noise_fields(s.noise))
    end
  end

  defp groups(%{type: :laser} = s, _index) do
    {px, py, pth} = s.pose
    {min_range, max_range} = s.range

    for angle <- beam_angles(pth, s.fov, s.beams) do
      %{
        x: px,
        y: py,
        heading: angle,
        fov: 0.0,
        rays: 1,
        min_range: min_range,
        max_range: max_range,
        max_bounces: 0,
        critical_angle: :math.pi() / 2,
        ring: -1
      }
      |> Map.merge(noise_fields(s.noise))
    end
  end

  defp groups(_s, _index), do: []

  defp beam_angles(centre, _fov, 1), do: [centre]

  defp beam_angles(centre, fov, beams),
    do: for(j <- 0..(beams - 1), do: centre - fov / 2 + j * fov / (beams - 1))

  defp noise_fields(noise) do
    %{
      noise_std: noise.stddev,
      noise_prop: noise.proportional,
      dropout: noise.miss_probability,
      spike: 0.0,
      spike_magnitude: 0.0,
      bias: 0.0
    }
  end

  defp payload_template(%{type: type} = s, groups, min_range, max_range) when type in @ranged do
    s
    |> static_payload(groups)
    |> Map.merge(%{ranges: [], range_min: min_range * 1.0, range_max: max_range * 1.0, stamp: 0.0})
  end

  defp payload_template(_s, _groups, _min_range, _max_range), do: %{}

  defp static_payload(%{type: :sonar}, groups),
    do: %{headings: Enum.map(groups, & &1.heading)}

  defp static_payload(%{type: :laser} = s, groups) do
    angles = Enum.map(groups, & &1.heading)
    {_, _, pth} = s.pose

    %{
      angle_min: List.first(angles) - pth,
      angle_max: List.last(angles) - pth,
      angle_increment: if(s.beams > 1, do: s.fov / (s.beams - 1), else: 0.0)
    }
  end

  # Whether each fault holds for this robot at all (stuck: per reading
  # group; dead and drift: the whole sensor), drawn once.
  defp draw_faults(faults, n_groups, rng) do
    Enum.map_reduce(faults, rng, fn f, rng ->
      case f.type do
        :stuck ->
          {hits, rng} =
            Enum.map_reduce(0..(n_groups - 1), rng, fn i, rng ->
              {u, rng} = :rand.uniform_s(rng)
              {if(u < f.probability, do: i), rng}
            end)

          {Map.put(f, :groups, Enum.reject(hits, &is_nil/1)), rng}

        type when type in [:dead, :drift] ->
          {u, rng} = :rand.uniform_s(rng)
          {Map.put(f, :holds, u < f.probability), rng}

        _per_reading ->
          {f, rng}
      end
    end)
  end

  @doc "Whether a sensor reads at this step."
  def due?(sensor, step), do: rem(step, sensor.every) == 0

  @doc """
  Reads one sensor of a robot. `robot` holds `:index`, `:pose`, `:odom`,
  `:odom_twist`, `:bumped`, `:rng`. Returns `{payload | nil, sensor,
  rng}` (nil: a dead sensor says nothing). With `packed`, a sonar's or
  laser's ranges are a binary (one little-endian float64 a reading).
  """
  def read(sensor, robot, world, time, seed, packed \\ false) do
    if dead?(sensor, time) do
      {nil, sensor, robot.rng}
    else
      do_read(sensor, robot, world, time, seed, packed)
    end
  end

  defp do_read(%{type: type} = sensor, robot, world, time, seed, packed) when type in @ranged do
    groups = packed_groups(sensor, time)

    ranges =
      if packed,
        do: Raycast.scan(world.raycast, robot.pose, groups, robot.index, seed),
        else: Raycast.scan_list(world.raycast, robot.pose, groups, robot.index, seed)

    {ranges, sensor} = faults(ranges, sensor, time)

    payload = %{sensor.payload | ranges: ranges, stamp: time}

    {payload, sensor, robot.rng}
  end

  defp do_read(%{type: :beacon_laser} = sensor, robot, world, time, _seed, _packed) do
    {detections, rng} = beacons(sensor, robot, world, time)
    {%{detections: detections, stamp: time}, sensor, rng}
  end

  defp do_read(%{type: :bumper} = sensor, robot, _world, time, _seed, _packed),
    do: {%{pressed: robot.bumped, stamp: time}, sensor, robot.rng}

  defp do_read(%{type: :odometry} = sensor, robot, _world, time, _seed, _packed),
    do: {%{pose: robot.odom, twist: robot.odom_twist, stamp: time}, sensor, robot.rng}

  # (these run for every sensor of every robot at every step: recursion,
  # no closures)
  defp dead?(sensor, time), do: dead_fault?(sensor.faults, time)

  defp dead_fault?([], _time), do: false
  defp dead_fault?([%{type: :dead, holds: true, after: t} | _], time) when time >= t, do: true
  defp dead_fault?([_ | rest], time), do: dead_fault?(rest, time)

  # The ray groups packed for the NIF, once for each set of per-reading
  # faults that can be active: they start one after the other, so the sets
  # are the prefixes of the faults in order of start. Latest start first.
  # (The groups themselves are not kept: the robot's state stays small.)
  defp packings([], _faults), do: []

  defp packings(groups, faults) do
    per_reading =
      faults |> Enum.filter(&(&1.type in [:dropout, :spikes])) |> Enum.sort_by(& &1.after)

    prefixes =
      for n <- 0..length(per_reading) do
        active = Enum.take(per_reading, n)
        start = if n == 0, do: 0.0, else: List.last(active).after * 1.0
        {start, shared_pack(Enum.map(groups, &apply_faults(&1, active)))}
      end

    Enum.reverse(prefixes)
  end

  # Robots of one description pack the same groups: they share one binary
  # per process (a shard), so a scan reads groups that are in the caches
  # and not one copy per robot (32 KB for a 180-beam laser).
  defp shared_pack(groups) do
    key = {__MODULE__, :packed, :erlang.phash2(groups)}

    case Process.get(key) do
      {^groups, packed} ->
        packed

      _ ->
        packed = Raycast.pack_groups(groups)
        Process.put(key, {groups, packed})
        packed
    end
  end

  defp packed_groups(sensor, time), do: started(sensor.packed, time)

  defp started([{start, packed} | _], time) when time >= start, do: packed
  defp started([_ | rest], time), do: started(rest, time)

  defp apply_faults(group, active) do
    Enum.reduce(active, group, fn
      %{type: :dropout, probability: p}, g ->
        %{g | dropout: 1 - (1 - g.dropout) * (1 - p)}

      %{type: :spikes, probability: p, magnitude: m}, g ->
        %{g | spike: p, spike_magnitude: abs(m)}
    end)
  end

  # The stateful faults, on a list of ranges; packed ranges are unpacked
  # for them only while one holds.
  defp faults(ranges, sensor, time) when is_list(ranges),
    do: ranges |> drift(sensor, time) |> stuck(sensor, time)

  defp faults(ranges, sensor, time) do
    if any_stateful?(sensor.faults, time) do
      list = for <<r::float-little-64 <- ranges>>, do: r
      {list, sensor} = faults(list, sensor, time)
      {for(r <- list, into: <<>>, do: <<r::float-little-64>>), sensor}
    else
      {ranges, sensor}
    end
  end

  defp any_stateful?([], _time), do: false
  defp any_stateful?([f | rest], time), do: stateful?(f, time) or any_stateful?(rest, time)

  defp stateful?(%{type: :drift, holds: true} = f, time), do: time >= f.after
  defp stateful?(%{type: :stuck, groups: [_ | _]} = f, time), do: time >= f.after
  defp stateful?(_fault, _time), do: false

  defp drift(ranges, sensor, time) do
    bias =
      for %{type: :drift, holds: true} = f <- sensor.faults, time >= f.after, reduce: 0.0 do
        acc -> acc + f.magnitude * (time - f.after)
      end

    if bias == 0.0 do
      ranges
    else
      max = sensor.max_range
      min = sensor.min_range
      Enum.map(ranges, fn r -> if r >= max, do: r, else: min(max(r + bias, min), max) end)
    end
  end

  # A stuck group keeps the reading it had when the fault started.
  defp stuck(ranges, sensor, time) do
    groups = for %{type: :stuck} = f <- sensor.faults, time >= f.after, g <- f.groups, do: g

    case groups do
      [] ->
        {ranges, sensor}

      groups ->
        stuck = Enum.reduce(groups, sensor.stuck, &Map.put_new(&2, &1, Enum.at(ranges, &1)))

        ranges =
          ranges
          |> Enum.with_index()
          |> Enum.map(fn {r, i} -> Map.get(stuck, i, r) end)

        {ranges, %{sensor | stuck: stuck}}
    end
  end

  # Range and bearing to each beacon within range and field of view and in
  # line of sight, with noise and missed detections.
  defp beacons(sensor, robot, world, time) do
    {x, y, th} = robot.pose
    {px, py, pth} = sensor.pose
    {c, s} = {:math.cos(th), :math.sin(th)}
    {sx, sy} = {x + c * px - s * py, y + s * px + c * py}
    heading = th + pth

    miss =
      sensor.noise.miss_probability +
        Enum.sum(for %{type: :dropout} = f <- sensor.faults, time >= f.after, do: f.probability)

    Enum.flat_map_reduce(world.beacons, robot.rng, fn %{name: name, at: {bx, by}}, rng ->
      {dx, dy} = {bx - sx, by - sy}
      range = :math.sqrt(dx * dx + dy * dy)
      angle = :math.atan2(dy, dx)
      bearing = normalize_angle(angle - heading)

      visible =
        range >= sensor.min_range and range <= sensor.max_range and
          abs(bearing) <= sensor.fov / 2 and
          line_of_sight?(world, robot.index, sx, sy, angle, range)

      {u, rng} = :rand.uniform_s(rng)

      if visible and u >= miss do
        {nr, rng} = :rand.normal_s(rng)
        {nb, rng} = :rand.normal_s(rng)
        sd = sensor.noise.stddev

        {[%{id: name, range: range + sd * nr, bearing: normalize_angle(bearing + sd * nb)}], rng}
      else
        {[], rng}
      end
    end)
  end

  defp line_of_sight?(world, exclude, sx, sy, angle, range) do
    [%{range: hit}] = Raycast.cast_rays(world.raycast, [{sx, sy, angle, range}], exclude: exclude)
    # a beacon on a wall is hit at its own distance
    hit >= range - 0.05
  end
end
