defmodule ThinkingCap.Control.Steering do
  @moduledoc """
  What a car-like drive (tricycle, Ackermann) can do with a body twist.

  A car cannot turn on the spot: its turn rate is bounded by its speed,
  `|omega| <= |v| * k` with `k = tan(max_steering) / wheelbase` the
  tightest curvature (`max_curvature/1`). The drive's limits
  (`ThinkingCap.Robot.Kinematics.limit/4`) cut the turn rate of a twist
  that asks for more, so a controller that says "stop and turn towards
  the goal" (`{0, omega}`) leaves a car standing still for ever.
  `feasible/4` turns such a twist into one the car can drive: creep along
  the tightest arc towards the same turn, forwards if the way ahead is
  clear, in reverse if only the way behind is (a turn in several moves),
  and stop if neither is.
  """

  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Robot.Kinematics

  @half_pi :math.pi() / 2

  @typedoc "Tightest curvature, 1/m (`:infinity` for a drive that turns on the spot)."
  @type curvature :: float() | :infinity

  @doc "The tightest curvature of a drive model (1/m), `:infinity` if it turns on the spot."
  @spec max_curvature(Kinematics.model()) :: curvature()
  def max_curvature(model) do
    cond do
      Kinematics.type(model) == :differential -> :infinity
      model.max_steering >= @half_pi -> :infinity
      true -> :math.tan(model.max_steering) / model.wheelbase
    end
  end

  @doc "The turning radius of the tightest turn, m (0.0 for a drive that turns on the spot)."
  @spec min_turning_radius(Kinematics.model()) :: float()
  def min_turning_radius(model) do
    case max_curvature(model) do
      :infinity -> 0.0
      k -> 1.0 / k
    end
  end

  @doc """
  A twist the drive can follow, as near as it can to `{v, omega}`.

  Twists within the curvature limit come back unchanged. Otherwise the
  speed is raised to what the turn needs, at most `creep` m/s, and the
  turn rate cut to the tightest arc at that speed, in the direction the
  twist asked for (reverse when `v < 0`). Going forwards needs `clear`
  metres (beyond `radius`) free ahead in `lps`, going back the same
  behind; without either the car stops. Without an LPS the way is taken
  as clear.

  Options: `creep:` (m/s, default 0.15), `radius:` (m, default 0.2),
  `clear:` (m, default 0.3).
  """
  @spec feasible({number(), number()}, curvature(), LPS.t() | nil, keyword()) ::
          {float(), float()}
  def feasible({v, w}, :infinity, _lps, _opts), do: {v * 1.0, w * 1.0}

  def feasible({v, w}, k, lps, opts) do
    if abs(w) <= abs(v) * k + 1.0e-9 do
      {v * 1.0, w * 1.0}
    else
      creep = Keyword.get(opts, :creep, 0.15)
      speed = min(max(abs(v), abs(w) / k), max(creep, abs(v)))
      wanted = if v < -1.0e-6, do: [:reverse, :forward], else: [:forward, :reverse]

      case Enum.find(wanted, &clear?(lps, &1, opts)) do
        nil ->
          {0.0, 0.0}

        direction ->
          v = if direction == :forward, do: speed, else: -speed
          # the same way round as asked: omega keeps its sign
          {v, sign(w) * min(abs(w), speed * k)}
      end
    end
  end

  defp clear?(nil, _direction, _opts), do: true

  defp clear?(%LPS{} = lps, direction, opts) do
    radius = Keyword.get(opts, :radius, 0.2)
    clear = Keyword.get(opts, :clear, 0.3)

    distance =
      case direction do
        :forward -> LPS.min_distance(lps, -1.0, 1.0)
        :reverse -> LPS.min_distance(lps, :math.pi() - 1.0, 1.0 - :math.pi())
      end

    distance > radius + clear
  end

  defp sign(x) when x < 0, do: -1.0
  defp sign(_x), do: 1.0
end
