defmodule ThinkingCap.Robot.Kinematics.Ackermann do
  @moduledoc """
  Ackermann (car-like) drive: a driven rear axle and two steered front
  wheels `track` (m) apart, `wheelbase` L (m) in front of the rear axle;
  the robot frame's origin is the middle of the rear axle. The actuation is
  `{:steer, u, delta}`: the rear axle's speed (m/s) and the
  bicycle-equivalent steering angle (rad, positive to the left), the angle
  of a virtual wheel in the middle of the front axle:

      v     = u
      omega = u tan delta / L

  The robot turns about a centre on the rear axle line at
  `turning_radius/2` = `L / tan delta`; `wheel_angles/2` gives the angles
  of the real front wheels, whose axes meet at that centre.
  `max_steering` bounds the bicycle angle.

  See `ThinkingCap.Robot.Kinematics` for the functions common to all drives.
  """

  @behaviour ThinkingCap.Robot.Kinematics

  alias ThinkingCap.Robot.Kinematics

  @enforce_keys [:wheelbase, :track, :max_steering]
  defstruct [
    :wheelbase,
    :track,
    :max_steering,
    max_speed: 1.0,
    max_turn_rate: 1.5,
    max_acceleration: 1.0
  ]

  @type t :: %__MODULE__{
          wheelbase: float(),
          track: float(),
          max_steering: float(),
          max_speed: float(),
          max_turn_rate: float(),
          max_acceleration: float()
        }

  @doc """
  Builds the model from the RDF's kinematics map (limits default as in the
  RDF). Raises `ArgumentError` unless `max_steering < π/2`.
  """
  @impl true
  @spec new(map()) :: t()
  def new(k) do
    max = Kinematics.fetch!(k, :max_steering, :ackermann)

    if max >= :math.pi() / 2,
      do:
        raise(
          ArgumentError,
          "kinematics: an ackermann drive needs max_steering: below π/2 rad, got #{max}"
        )

    Kinematics.build!(__MODULE__, k, :ackermann)
  end

  @doc "The body twist of the rear axle speed and bicycle steering angle `{:steer, u, delta}`."
  @impl true
  @spec forward(t(), Kinematics.actuation()) :: Kinematics.twist()
  def forward(%__MODULE__{wheelbase: l}, {:steer, u, delta}),
    do: {u / 1, u * :math.tan(delta) / l}

  @doc """
  The rear axle speed and bicycle steering angle `{:steer, v, delta}` for
  the twist `{v, omega}`: `tan delta = omega L / v`. A `delta` beyond
  `±max_steering` (and any `omega != 0` at `v = 0`) is clamped to the
  limit; the speed stays `v`.
  """
  @impl true
  @spec inverse(t(), Kinematics.twist()) :: Kinematics.actuation()
  def inverse(%__MODULE__{wheelbase: l, max_steering: max}, {v, omega}) do
    delta =
      cond do
        omega == 0 -> 0.0
        v == 0 -> if omega > 0, do: max, else: -max
        true -> :math.atan(omega * l / v)
      end

    {:steer, v / 1, Kinematics.clamp(delta, -max, max)}
  end

  @doc """
  Speed, turn rate and acceleration limits, and the steering limit
  `|omega| <= |v| tan(max_steering) / L`. See
  `ThinkingCap.Robot.Kinematics.limit/4`.
  """
  @impl true
  @spec limit(t(), Kinematics.twist(), Kinematics.twist(), number()) :: Kinematics.twist()
  def limit(%__MODULE__{wheelbase: l, max_steering: max} = model, wanted, previous, dt),
    do: Kinematics.apply_limits(model, wanted, previous, dt, :math.tan(max) / l)

  @doc """
  The signed turning radius (m) of the rear axle's middle for a bicycle
  steering angle: `L / tan delta`, positive turning left (the centre is at
  `{0, R}` in the robot frame), `:infinity` at `delta = 0`.
  """
  @spec turning_radius(t(), number()) :: float() | :infinity
  def turning_radius(_model, delta) when delta == 0, do: :infinity
  def turning_radius(%__MODULE__{wheelbase: l}, delta), do: l / :math.tan(delta)

  @doc """
  The angles `{left, right}` (rad) of the two front wheels for a bicycle
  steering angle, so that both wheels' axes pass through the turning
  centre `{0, R}`: `tan delta_left = L / (R - t/2)`,
  `tan delta_right = L / (R + t/2)` with `R = L / tan delta` and `t` the
  track. Turning left the left wheel is the inner one (the larger angle).
  """
  @spec wheel_angles(t(), number()) :: {float(), float()}
  def wheel_angles(%__MODULE__{wheelbase: l, track: t}, delta) do
    # tan δ_left = L / (L / tan δ - t/2) = L tan δ / (L - t/2 tan δ), defined at δ = 0 too
    tan = :math.tan(delta)
    {:math.atan2(l * tan, l - t / 2 * tan), :math.atan2(l * tan, l + t / 2 * tan)}
  end
end
