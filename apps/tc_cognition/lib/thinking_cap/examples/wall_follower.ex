defmodule ThinkingCap.Examples.WallFollower do
  @moduledoc """
  Follows the wall on one side at a set distance, and slows down, then
  stops and turns away, as an obstacle ahead gets near: the module
  written from scratch in the module author's guide
  (`docs/module_guide.md`).

  It reads the robot's Local Perceptual Space (`{:lps, robot, lps}`, from
  `ThinkingCap.Perception.Fuser`) and, every period, writes the command
  for the robot's base: `{:drive, robot, %{command: {:velocity, v, w}}}`.

      follower: [
        module: ThinkingCap.Examples.WallFollower,
        activity: :periodic, period: 0.1, deadline: 0.05, priority: 80,
        params: [side: :right, distance: 0.6, speed: 0.3]
      ]

  Its params (`params/0`) are checked when the ADF is read; all but
  `side` can be changed while it runs (`handle_param/3`).
  """
  use ThinkingCap.Module

  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Tuples
  require Tuples

  @impl true
  def params do
    [
      side:
        {{:one_of, [:left, :right]},
         default: :right, read_only: true, doc: "the side the wall is kept on"},
      distance: {{:number_range, 0.2, 2.0}, default: 0.5, doc: "m from the wall to keep"},
      speed: {{:number_range, 0.0, 1.0}, default: 0.3, doc: "m/s when the way ahead is clear"},
      gain:
        {{:number_range, 0.1, 10.0}, default: 1.5, doc: "rad/s of turn per m (or rad) of error"},
      max_turn_rate: {{:number_range, 0.1, 3.0}, default: 1.0, doc: "rad/s at most"},
      slow_within:
        {{:number_range, 0.2, 5.0},
         default: 1.0, doc: "m: an obstacle ahead nearer than this slows the robot down"},
      stop_within:
        {{:number_range, 0.1, 2.0},
         default: 0.4, doc: "m: an obstacle ahead nearer than this stops it (it turns in place)"}
    ]
  end

  @impl true
  def init(_params, context) do
    # context.params: the ADF's params, checked against params/0, with
    # the defaults of those it does not give
    state = Map.merge(context.params, %{robot: context.robot, lps: nil})
    {[subscribe: Tuples.lps(context.robot)], state}
  end

  @impl true
  def handle_tuple(Tuples.lps(robot, %LPS{} = lps), %{robot: robot} = state),
    do: {[], %{state | lps: lps}}

  def handle_tuple(_tuple, state), do: {[], state}

  @impl true
  def handle_cycle(_release, state) do
    command = if state.lps, do: steer(state.lps, state), else: :stop
    drive = Tuples.drive(state.robot, %{command: command})
    {[out: Tuples.keyed(drive)], state}
  end

  @impl true
  def handle_param(:stop_within, value, state) when value >= state.slow_within,
    do: {:error, "stop_within must be below slow_within (#{state.slow_within} m)", state}

  def handle_param(:slow_within, value, state) when value <= state.stop_within,
    do: {:error, "slow_within must be above stop_within (#{state.stop_within} m)", state}

  def handle_param(key, value, state), do: {[], %{state | key => value}}

  @doc """
  The command for one LPS (`state` holds the params): the speed limited
  by the nearest obstacle ahead; the turn rate towards the wall's
  distance and direction, or away from the wall's side when something
  is ahead.
  """
  @spec steer(LPS.t(), map()) :: {:velocity, float(), float()}
  def steer(lps, state) do
    ahead = LPS.min_distance(lps, -0.35, 0.35)
    room = (ahead - state.stop_within) / (state.slow_within - state.stop_within)
    v = state.speed * clamp(room, 0.0, 1.0)
    # +1 when the wall is on the left: turning towards it is counter-clockwise
    sign = if state.side == :left, do: 1.0, else: -1.0

    w =
      cond do
        ahead < state.slow_within ->
          -sign * state.max_turn_rate * clamp(1.0 - room, 0.2, 1.0)

        wall = wall(lps, sign) ->
          {distance, direction} = wall
          state.gain * (sign * (distance - state.distance) + direction)

        true ->
          # no wall beside: curve towards its side to find one
          sign * state.max_turn_rate / 2
      end

    {:velocity, v, clamp(w, -state.max_turn_rate, state.max_turn_rate)}
  end

  # The wall beside, from two rays 0.4 rad either side of the perpendicular:
  # its distance and its direction in the robot's frame (0: parallel to
  # the robot's heading), or nil when a ray sees nothing.
  defp wall(lps, sign) do
    beside = sign * :math.pi() / 2

    with {x1, y1} <- point(lps, beside - sign * 0.4),
         {x2, y2} <- point(lps, beside + sign * 0.4) do
      length = max(:math.sqrt((x1 - x2) ** 2 + (y1 - y2) ** 2), 1.0e-6)
      {abs(x1 * y2 - x2 * y1) / length, :math.atan2(y1 - y2, x1 - x2)}
    end
  end

  # where the ray at `angle` meets an obstacle (nil: beyond the LPS's range)
  defp point(lps, angle) do
    case LPS.distance_at(lps, angle) do
      d when d >= lps.range -> nil
      d -> {d * :math.cos(angle), d * :math.sin(angle)}
    end
  end

  defp clamp(x, low, high), do: max(low, min(high, x))
end
