defmodule ThinkingCap.Robot.OdometryError do
  @moduledoc """
  What the wheels really do versus what the encoders say: the odometry
  error model of the RDF's `odometry_error:` section, for a simulator (or
  a test) to move a robot truthfully while reporting the odometry a real
  one would.

  Each `step/3` takes the commanded twist and returns the twist the robot
  really moved with and the twist its odometry reports, over that step:

    1. the controller turns the command into actuation with the **nominal**
       geometry (`ThinkingCap.Robot.Kinematics.inverse/2`): wheel speeds, or
       speed and steering;
    2. the robot moves by that actuation with its **actual** geometry
       (`ThinkingCap.Robot.Kinematics.forward/2` with the real wheels) plus
       random slip;
    3. the encoders measure the actuation (wheel rotation, steering angle)
       and the odometry turns it back into a twist with the **nominal**
       geometry; encoders do not see slip.

  ## Parameters

    * `wheel_diameter_ratio` `E_d = D_right / D_left` (Borenstein's
      wheel-diameter error): the actual wheel radii are
      `r_left = 2 r / (E_d + 1)` and `r_right = 2 r E_d / (E_d + 1)`, so
      their mean stays the nominal `r`. A commanded straight line becomes an
      arc of curvature `2 (E_d - 1) / ((E_d + 1) b_actual)`. Differential
      drives only: a car-like drive has one steering angle setting its
      curvature, and the ratio is not used there.
    * `wheelbase_ratio` = actual / nominal wheel separation `b`
      (differential) or wheelbase `L` (tricycle, Ackermann): the robot
      really turns by the odometry's angle divided by the ratio.
    * `slip` - the standard deviation of the distance error after one
      metre driven: each step's distance `ds` gets Gaussian noise of
      standard deviation `slip * sqrt(|ds|)`;
    * `turn_slip` - the standard deviation of the heading error after one
      radian turned: each step's rotation `dθ` gets Gaussian noise of
      standard deviation `turn_slip * sqrt(|dθ|)`.

  Variances grow linearly with distance and angle, so the statistics do not
  depend on the step size. The random numbers come from an explicit
  `:rand` state (`:exsss`) seeded by `new/3` and carried in the struct: a
  run is the same for the same seed, and the process dictionary is never
  used.

  With ratios 1.0 and slips 0, the true and the odometry twists are the
  commanded one (up to rounding, and to what `inverse/2` clamps for a
  car-like drive). Limits (`ThinkingCap.Robot.Kinematics.limit/4`) are the
  caller's business, before `step/3`.
  """

  alias ThinkingCap.Robot.Kinematics
  alias ThinkingCap.Robot.Kinematics.{Ackermann, Differential, Tricycle}

  @enforce_keys [:nominal, :actual, :rand]
  defstruct [
    :nominal,
    :actual,
    :rand,
    wheel_diameter_ratio: 1.0,
    wheelbase_ratio: 1.0,
    slip: 0.0,
    turn_slip: 0.0
  ]

  @typedoc """
  `nominal` is the model the controller and odometry use; `actual` the
  real geometry: for a differential drive
  `%{left_radius: m, right_radius: m, wheel_separation: m}`, for a car-like
  drive the model with its actual wheelbase.
  """
  @type t :: %__MODULE__{
          nominal: Kinematics.model(),
          actual: map(),
          rand: :rand.state(),
          wheel_diameter_ratio: float(),
          wheelbase_ratio: float(),
          slip: float(),
          turn_slip: float()
        }

  @defaults %{wheel_diameter_ratio: 1.0, wheelbase_ratio: 1.0, slip: 0.0, turn_slip: 0.0}

  @doc """
  Builds the error model for a kinematics model from the RDF's
  `odometry_error` map (or keyword list; missing keys take the RDF's
  defaults: ratios 1.0, slips 0.0) and a seed (an integer, or anything
  `:rand.seed_s/2` takes).
  """
  @spec new(Kinematics.model(), map() | keyword(), term()) :: t()
  def new(model, odometry_error, seed) do
    params =
      Enum.reduce(Map.new(odometry_error), @defaults, fn
        {key, value}, acc when is_map_key(@defaults, key) and is_number(value) ->
          Map.put(acc, key, value / 1)

        _, acc ->
          acc
      end)

    %__MODULE__{
      nominal: model,
      actual: actual(model, params),
      rand: :rand.seed_s(:exsss, seed),
      wheel_diameter_ratio: params.wheel_diameter_ratio,
      wheelbase_ratio: params.wheelbase_ratio,
      slip: params.slip,
      turn_slip: params.turn_slip
    }
  end

  defp actual(%Differential{wheel_radius: r, wheel_separation: b}, params) do
    e = params.wheel_diameter_ratio

    %{
      left_radius: 2 * r / (e + 1),
      right_radius: 2 * r * e / (e + 1),
      wheel_separation: b * params.wheelbase_ratio
    }
  end

  defp actual(%module{wheelbase: l} = model, params) when module in [Tricycle, Ackermann],
    do: %{model | wheelbase: l * params.wheelbase_ratio}

  @doc """
  One step of `dt` seconds (> 0) under the commanded twist: returns
  `{true_twist, odometry_twist, err}`, the twist the robot really moved
  with (slip included) and the one its odometry reports, each constant
  over the step (integrate poses with `ThinkingCap.Robot.Kinematics.integrate/3`).
  """
  @spec step(t(), Kinematics.twist(), number()) ::
          {Kinematics.twist(), Kinematics.twist(), t()}
  def step(%__MODULE__{} = err, {_v, _omega} = commanded, dt) when is_number(dt) and dt > 0 do
    actuation = Kinematics.inverse(err.nominal, commanded)
    odometry = Kinematics.forward(err.nominal, actuation)
    {v, omega} = really(err, actuation)

    {ds, rand} = noisy(v * dt, err.slip, err.rand)
    {dtheta, rand} = noisy(omega * dt, err.turn_slip, rand)

    {{ds / dt, dtheta / dt}, odometry, %{err | rand: rand}}
  end

  defp really(%{nominal: %Differential{}, actual: a}, {:wheels, left, right}) do
    {vl, vr} = {a.left_radius * left, a.right_radius * right}
    {(vl + vr) / 2, (vr - vl) / a.wheel_separation}
  end

  defp really(%{actual: model}, actuation), do: Kinematics.forward(model, actuation)

  # x plus Gaussian noise of variance sigma² |x|
  defp noisy(x, sigma, rand) when sigma == 0 or x == 0, do: {x / 1, rand}

  defp noisy(x, sigma, rand) do
    {n, rand} = :rand.normal_s(rand)
    {x + n * sigma * :math.sqrt(abs(x)), rand}
  end
end
