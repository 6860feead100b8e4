defmodule ThinkingCap.Robot.Kinematics.Tricycle do
  @moduledoc """
  Tricycle drive (a forklift, a three-wheeled AGV): one steered front
  wheel that also drives, `wheelbase` L (m) in front of the rear axle of
  two idle wheels; the robot frame's origin is the middle of the rear
  axle. The actuation is `{:steer, u, delta}`: the front wheel's ground
  speed (m/s) and steering angle (rad, positive to the left):

      v     = u cos delta
      omega = u sin delta / L

  so the robot turns about a centre on the rear axle line at a radius
  `v / omega = L / tan delta`. With `max_steering` of π/2 or more it turns
  on the spot.

  See `ThinkingCap.Robot.Kinematics` for the functions common to all drives.
  """

  @behaviour ThinkingCap.Robot.Kinematics

  alias ThinkingCap.Robot.Kinematics

  @enforce_keys [:wheelbase, :max_steering]
  defstruct [:wheelbase, :max_steering, max_speed: 1.0, max_turn_rate: 1.5, max_acceleration: 1.0]

  @type t :: %__MODULE__{
          wheelbase: float(),
          max_steering: float(),
          max_speed: float(),
          max_turn_rate: float(),
          max_acceleration: float()
        }

  @doc "Builds the model from the RDF's kinematics map (limits default as in the RDF)."
  @impl true
  @spec new(map()) :: t()
  def new(k), do: Kinematics.build!(__MODULE__, k, :tricycle)

  @doc "The body twist of the front wheel's speed and steering angle `{:steer, u, delta}`."
  @impl true
  @spec forward(t(), Kinematics.actuation()) :: Kinematics.twist()
  def forward(%__MODULE__{wheelbase: l}, {:steer, u, delta}),
    do: {u * :math.cos(delta), u * :math.sin(delta) / l}

  @doc """
  The front wheel's speed and steering angle `{:steer, u, delta}` for the
  twist `{v, omega}`: `tan delta = omega L / v`, `u = ±sqrt(v² + (omega L)²)`
  with the sign of `v`. A `delta` beyond `±max_steering` is clamped and `u`
  keeps `v` (`u = v / cos delta`), so the robot turns as fast as it can.
  """
  @impl true
  @spec inverse(t(), Kinematics.twist()) :: Kinematics.actuation()
  def inverse(%__MODULE__{wheelbase: l, max_steering: max}, {v, omega}) do
    h = :math.sqrt(v * v + omega * l * omega * l)
    # reversing: the wheel points the same way and rolls backwards
    {u, delta} =
      if v >= 0, do: {h, :math.atan2(omega * l, v)}, else: {-h, :math.atan2(-omega * l, -v)}

    if abs(delta) <= max do
      {:steer, u / 1, delta}
    else
      delta = Kinematics.clamp(delta, -max, max)
      {:steer, v / :math.cos(delta), delta}
    end
  end

  @doc """
  Speed, turn rate and acceleration limits, and the steering limit
  `|omega| <= |v| tan(max_steering) / L` (none when `max_steering >= π/2`).
  See `ThinkingCap.Robot.Kinematics.limit/4`.
  """
  @impl true
  @spec limit(t(), Kinematics.twist(), Kinematics.twist(), number()) :: Kinematics.twist()
  def limit(%__MODULE__{wheelbase: l, max_steering: max} = model, wanted, previous, dt) do
    curvature = if max >= :math.pi() / 2, do: :infinity, else: :math.tan(max) / l
    Kinematics.apply_limits(model, wanted, previous, dt, curvature)
  end
end
