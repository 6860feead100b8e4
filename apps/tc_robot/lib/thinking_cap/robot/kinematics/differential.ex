defmodule ThinkingCap.Robot.Kinematics.Differential do
  @moduledoc """
  Differential drive: two driven wheels of radius `wheel_radius` (m),
  `wheel_separation` (m) apart on one axle; the robot frame's origin is the
  middle of the axle. The actuation is `{:wheels, left, right}`, the
  wheels' angular speeds in rad/s (positive rolls the robot forward):

      v     = r (w_left + w_right) / 2
      omega = r (w_right - w_left) / b

  See `ThinkingCap.Robot.Kinematics` for the functions common to all drives.
  """

  @behaviour ThinkingCap.Robot.Kinematics

  alias ThinkingCap.Robot.Kinematics

  @enforce_keys [:wheel_radius, :wheel_separation]
  defstruct [
    :wheel_radius,
    :wheel_separation,
    max_speed: 1.0,
    max_turn_rate: 1.5,
    max_acceleration: 1.0
  ]

  @type t :: %__MODULE__{
          wheel_radius: float(),
          wheel_separation: float(),
          max_speed: float(),
          max_turn_rate: float(),
          max_acceleration: float()
        }

  @doc "Builds the model from the RDF's kinematics map (limits default as in the RDF)."
  @impl true
  @spec new(map()) :: t()
  def new(k), do: Kinematics.build!(__MODULE__, k, :differential)

  @doc "The body twist `{v, omega}` of wheel angular speeds `{:wheels, left, right}` (rad/s)."
  @impl true
  @spec forward(t(), Kinematics.actuation()) :: Kinematics.twist()
  def forward(%__MODULE__{wheel_radius: r, wheel_separation: b}, {:wheels, left, right}),
    do: {r * (left + right) / 2, r * (right - left) / b}

  @doc "The wheel angular speeds `{:wheels, left, right}` (rad/s) giving the twist `{v, omega}`."
  @impl true
  @spec inverse(t(), Kinematics.twist()) :: Kinematics.actuation()
  def inverse(model, twist), do: wheel_speeds(model, twist)

  @doc "Same as `inverse/2`: the wheel angular speeds for a twist."
  @spec wheel_speeds(t(), Kinematics.twist()) :: {:wheels, float(), float()}
  def wheel_speeds(%__MODULE__{wheel_radius: r, wheel_separation: b}, {v, omega}),
    do: {:wheels, (v - omega * b / 2) / r, (v + omega * b / 2) / r}

  @doc "Speed, turn rate and acceleration limits (see `ThinkingCap.Robot.Kinematics.limit/4`)."
  @impl true
  @spec limit(t(), Kinematics.twist(), Kinematics.twist(), number()) :: Kinematics.twist()
  def limit(model, wanted, previous, dt),
    do: Kinematics.apply_limits(model, wanted, previous, dt, :infinity)
end
