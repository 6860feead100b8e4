defmodule ThinkingCap.Sim.Wander do
  @moduledoc """
  Safe wandering (`ThinkingCap.Sim.Controller`): drive ahead, slow down
  as the way ahead closes in, turn away from the nearer side, turn on the
  spot when blocked, and now and then pick a new random heading bias. It
  reads the robot's laser, or its sonar ring when it has no laser; with
  neither it stays put.

  Args: `speed` (m/s, default: the robot's max_speed, at most 0.5),
  `turn_rate` (rad/s, default 1.0), `safe` (clearance ahead to keep, m,
  default 0.5), `seed`.
  """

  import ThinkingCap.Geometry, only: [normalize_angle: 1]
  alias ThinkingCap.Sim.Raycast

  @behaviour ThinkingCap.Sim.Controller

  @impl true
  def init(args, %{robot: robot, description: d}) do
    limits = Map.from_struct(d.kinematics)

    ranged =
      Enum.find(d.sensors, &(&1.type == :laser)) || Enum.find(d.sensors, &(&1.type == :sonar))

    %{
      sensor: ranged && ranged.name,
      speed: args[:speed] || min(Map.get(limits, :max_speed, 0.5), 0.5),
      turn_rate: args[:turn_rate] || 1.0,
      safe: args[:safe] || 0.5 + d.footprint.radius,
      bias: 0.0,
      turning: 0,
      last: :stop,
      layout: nil,
      rng: :rand.seed_s(:exsss, {args[:seed] || :erlang.phash2(robot), 17, 4})
    }
  end

  @impl true
  def packed_ranges?, do: true

  @impl true
  def control(readings, %{sensor: nil} = state) when is_map(readings), do: {:stop, state}

  def control(readings, %{sensor: sensor} = state) do
    case readings do
      %{bumper: %{pressed: true}} ->
        turn_away(state, 10)

      %{^sensor => payload} ->
        {sectors, state} = sectors(payload, state)
        steer(sectors, state)

      _ ->
        {state.last, state}
    end
  end

  # nearest obstacle to the front, left and right: the sectors' beam
  # indexes are worked out once per scan layout
  defp sectors(%{ranges: ranges} = payload, state) do
    n = count(ranges)
    key = layout_key(payload, n)

    layout =
      case state.layout do
        {^key, layout} -> layout
        _ -> layout(payload, n)
      end

    {nearest(ranges, layout), %{state | layout: {key, layout}}}
  end

  defp count(ranges) when is_binary(ranges), do: div(byte_size(ranges), 8)
  defp count(ranges), do: length(ranges)

  defp layout_key(%{angle_min: a0, angle_increment: inc}, n), do: {:scan, a0, inc, n}
  defp layout_key(%{headings: headings}, _n), do: {:ring, headings}

  # a laser: three contiguous slices {first, count}
  defp layout(%{angle_min: a0, angle_increment: inc}, n) when inc > 0 do
    slice = fn lo, hi ->
      first = max(0, ceil((lo - a0) / inc))
      last = min(n - 1, floor((hi - a0) / inc))
      {first, max(0, last - first + 1)}
    end

    {:slices, slice.(-0.5, 0.5), slice.(0.5, 1.6), slice.(-1.6, -0.5)}
  end

  # a ring: the sector of each transducer
  defp layout(payload, n) do
    angles =
      case payload do
        %{headings: headings} -> Enum.map(headings, &normalize_angle/1)
        %{angle_min: a0} -> List.duplicate(a0, n)
      end

    {:ring, Enum.map(angles, &sector/1)}
  end

  defp sector(a) when abs(a) <= 0.5, do: :front
  defp sector(a) when a > 0.5 and a <= 1.6, do: :left
  defp sector(a) when a < -0.5 and a >= -1.6, do: :right
  defp sector(_a), do: nil

  defp nearest(ranges, {:slices, front, left, right}),
    do: {slice_min(ranges, front), slice_min(ranges, left), slice_min(ranges, right)}

  defp nearest(ranges, {:ring, sectors}), do: ring_min(ranges, sectors, {100.0, 100.0, 100.0})

  defp slice_min(_ranges, {_first, 0}), do: 100.0

  defp slice_min(ranges, {first, count}) when is_binary(ranges),
    do: Raycast.ranges_min(ranges, first, count)

  defp slice_min(ranges, {first, count}),
    do: ranges |> :lists.sublist(first + 1, count) |> :lists.min()

  defp ring_min(<<r::float-little-64, rs::binary>>, [s | ss], acc),
    do: ring_min(rs, ss, sector_min(s, r, acc))

  defp ring_min([r | rs], [s | ss], acc), do: ring_min(rs, ss, sector_min(s, r, acc))
  defp ring_min(_, _, acc), do: acc

  defp sector_min(:front, r, {f, l, ri}), do: {min(f, r), l, ri}
  defp sector_min(:left, r, {f, l, ri}), do: {f, min(l, r), ri}
  defp sector_min(:right, r, {f, l, ri}), do: {f, l, min(ri, r)}
  defp sector_min(nil, _r, acc), do: acc

  defp steer({front, left, right}, state) do
    cond do
      state.turning > 0 ->
        turn_away(%{state | turning: state.turning - 1}, 0)

      front < state.safe ->
        turn_away(state, 5)

      true ->
        {u, rng} = :rand.uniform_s(state.rng)
        bias = if u < 0.05, do: (u * 20 - 0.5) * state.turn_rate, else: state.bias
        away = if left < right, do: -1.0, else: 1.0
        nearest = min(left, right)
        avoid = if nearest < state.safe, do: away * state.turn_rate * 0.8, else: 0.0
        v = state.speed * min(1.0, (front - state.safe * 0.5) / (2 * state.safe))
        command = {:velocity, max(v, 0.05), bias * 0.3 + avoid}
        {command, %{state | bias: bias, rng: rng, last: command}}
    end
  end

  defp turn_away(state, steps) do
    direction = if state.bias >= 0, do: 1.0, else: -1.0
    command = {:velocity, 0.0, direction * state.turn_rate}
    {command, %{state | turning: max(state.turning, steps), last: command}}
  end
end
