defmodule ThinkingCap.Robot.Kinematics do
  @moduledoc """
  Drive models: how wheel speeds and steering make the robot move, and back.

  Three models, one struct each, built from the RDF's `kinematics:` section
  by `new/1`:

    * `ThinkingCap.Robot.Kinematics.Differential` - two driven wheels on
      one axle; actuation `{:wheels, left, right}`, wheel angular speeds in
      rad/s (positive rolls the robot forward);
    * `ThinkingCap.Robot.Kinematics.Tricycle` - one steered front wheel
      that also drives, `wheelbase` in front of the rear axle; actuation
      `{:steer, u, delta}`, the front wheel's ground speed (m/s) and
      steering angle (rad);
    * `ThinkingCap.Robot.Kinematics.Ackermann` - a car: driven rear axle,
      two steered front wheels `track` apart; actuation `{:steer, u, delta}`,
      the rear axle's speed (m/s) and the bicycle-equivalent steering angle
      (rad; `Ackermann.wheel_angles/2` gives each front wheel's angle).

  The robot frame is REP-103 (x forward, y left, θ counter-clockwise) with
  its origin at the middle of the (rear) axle; a twist `{v, omega}` is the
  body's forward speed (m/s) and turn rate (rad/s).

  Every model implements this module's behaviour; the functions here
  dispatch on the struct:

      model = Kinematics.new(%{type: :differential, wheel_radius: 0.033, wheel_separation: 0.16})
      {:wheels, l, r} = Kinematics.inverse(model, {0.2, 0.5})
      {0.2, 0.5} = Kinematics.forward(model, {:wheels, l, r})  # up to rounding
      pose = Kinematics.integrate({0.0, 0.0, 0.0}, {0.2, 0.5}, 0.1)

  ## Limits

  `limit/4` applies the RDF's limits to a wanted twist, in this order:

    1. `|v| <= max_speed`;
    2. `|v - v_prev| <= max_acceleration * dt`;
    3. `|omega| <= max_turn_rate`;
    4. `|omega - omega_prev| <= max_angular_acceleration * dt`, where the
       angular acceleration limit is
       `max_angular_acceleration = max_acceleration * max_turn_rate / max_speed`:
       from rest, full turn rate takes as long as full speed;
    5. car-like drives only: `|omega| <= |v| * tan(max_steering) / wheelbase`
       with the `v` of step 2 (a car cannot turn faster than its steering
       lets it at the speed it has). This geometric limit wins over the
       angular acceleration limit when both cannot hold.

  The limits of a differential drive are on the body twist; the RDF gives
  no wheel speed limit, so the outer wheel of a fast turn may exceed
  `max_speed`.
  """

  alias ThinkingCap.Robot.Kinematics.{Ackermann, Differential, Tricycle}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @typedoc "Body velocity: forward speed (m/s) and turn rate (rad/s, counter-clockwise)."
  @type twist :: {v :: float(), omega :: float()}

  @typedoc "Planar pose: x, y (m), heading θ (rad, in (−π, π])."
  @type pose :: {x :: float(), y :: float(), theta :: float()}

  @typedoc """
  What the motors are told: differential wheel angular speeds (rad/s), or a
  steered drive's speed (m/s) and steering angle (rad).
  """
  @type actuation ::
          {:wheels, left :: float(), right :: float()}
          | {:steer, speed :: float(), angle :: float()}

  @type model :: Differential.t() | Tricycle.t() | Ackermann.t()

  @type drive :: :differential | :tricycle | :ackermann

  @doc "Builds the model from the RDF's kinematics map (see `ThinkingCap.Robot.Kinematics.new/1`)."
  @callback new(map()) :: model()

  @doc "The body twist an actuation produces."
  @callback forward(model(), actuation()) :: twist()

  @doc "The actuation producing a twist (clamped where the drive cannot)."
  @callback inverse(model(), twist()) :: actuation()

  @doc "Applies the model's limits to a wanted twist given the previous one and the time step."
  @callback limit(model(), twist(), twist(), dt :: float()) :: twist()

  @limit_defaults %{max_speed: 1.0, max_turn_rate: 1.5, max_acceleration: 1.0}

  @models %{differential: Differential, tricycle: Tricycle, ackermann: Ackermann}
  @drives Map.new(@models, fn {drive, module} -> {module, drive} end)

  @doc """
  Builds a model from the RDF's `kinematics` map (or keyword list): `type`
  chooses the model, the drive's geometry (`wheel_radius` and
  `wheel_separation`; `wheelbase` and `max_steering`; plus `track` for
  Ackermann) is required, and limits missing (or `nil`) take the RDF's
  defaults (`max_speed` 1.0 m/s, `max_turn_rate` 1.5 rad/s,
  `max_acceleration` 1.0 m/s²).

  Raises `ArgumentError` naming a missing or non-positive parameter.
  """
  @spec new(map() | keyword()) :: model()
  def new(kinematics) when is_list(kinematics), do: kinematics |> Map.new() |> new()

  def new(%{type: type} = kinematics) when is_map_key(@models, type) do
    kinematics =
      Enum.reduce(@limit_defaults, kinematics, fn {key, default}, k ->
        if Map.get(k, key) == nil, do: Map.put(k, key, default), else: k
      end)

    @models[type].new(kinematics)
  end

  def new(kinematics),
    do:
      raise(
        ArgumentError,
        "kinematics: expected type: :differential, :tricycle or :ackermann, got #{inspect(kinematics[:type])}"
      )

  @doc "The drive of a model: `:differential`, `:tricycle` or `:ackermann`."
  @spec type(model()) :: drive()
  # by module name, not struct pattern: the models compile after this behaviour
  def type(%module{}) when is_map_key(@drives, module), do: @drives[module]

  @doc "The model's limits: `max_speed`, `max_turn_rate`, `max_acceleration` and, if steered, `max_steering`."
  @spec limits(model()) :: %{atom() => float()}
  def limits(model),
    do:
      model
      |> Map.from_struct()
      |> Map.take([:max_speed, :max_turn_rate, :max_acceleration, :max_steering])

  @doc """
  The body twist `{v, omega}` an actuation produces.

    * differential, `{:wheels, wl, wr}`: `v = r (wl + wr) / 2`,
      `omega = r (wr - wl) / b`;
    * tricycle, `{:steer, u, delta}` (front wheel speed and angle):
      `v = u cos delta`, `omega = u sin delta / L`;
    * Ackermann, `{:steer, u, delta}` (rear axle speed, bicycle angle):
      `v = u`, `omega = u tan delta / L`.
  """
  @spec forward(model(), actuation()) :: twist()
  def forward(%module{} = model, actuation), do: module.forward(model, actuation)

  @doc """
  The actuation giving the twist `{v, omega}`: exact for a differential
  drive. For car-like drives the steering angle is clamped to
  `±max_steering`: an `omega` that needs more (including any `omega != 0`
  at `v = 0`) keeps `v` and gets the largest turn rate the clamped
  steering gives (zero at `v = 0`, where the wheel is still steered
  towards the turn). A tricycle whose `max_steering` reaches π/2 turns on
  the spot exactly (`delta = ±π/2`).
  """
  @spec inverse(model(), twist()) :: actuation()
  def inverse(%module{} = model, twist), do: module.inverse(model, twist)

  @doc """
  Limits a wanted twist given the previous (applied) one and the time step
  `dt` (s): speed, turn rate, linear and angular acceleration, and for
  car-like drives the steering limit. See "Limits" in the moduledoc for the
  order and the angular acceleration limit.
  """
  @spec limit(model(), twist(), twist(), number()) :: twist()
  def limit(%module{} = model, wanted, previous, dt),
    do: module.limit(model, wanted, previous, dt)

  @doc """
  The pose after moving with the constant twist `{v, omega}` for `dt`
  seconds from `pose`: the exact circular arc (a straight line when
  `omega` is 0; no loss of precision as `omega` approaches 0). θ is
  normalised to (−π, π].
  """
  @spec integrate(pose(), twist(), number()) :: pose()
  def integrate({x, y, theta}, {v, omega}, dt) do
    dtheta = omega * dt
    # chord of the arc: length v dt sinc(dθ/2), direction θ + dθ/2
    chord = v * dt * sinc(dtheta / 2)
    heading = theta + dtheta / 2

    {x + chord * :math.cos(heading), y + chord * :math.sin(heading),
     normalize_angle(theta + dtheta)}
  end

  defp sinc(a) when abs(a) < 1.0e-4, do: 1.0 - a * a / 6.0
  defp sinc(a), do: :math.sin(a) / a

  @doc false
  # The limits shared by every model (steps 1-4 of "Limits"), then the
  # curvature limit `max_curvature` (1/m, or :infinity) of step 5.
  @spec apply_limits(model(), twist(), twist(), number(), number() | :infinity) :: twist()
  def apply_limits(model, {v, omega}, {v0, omega0}, dt, max_curvature) do
    dt = max(dt, 0.0)
    max_alpha = model.max_acceleration * model.max_turn_rate / model.max_speed

    v =
      v
      |> clamp(-model.max_speed, model.max_speed)
      |> clamp(v0 - model.max_acceleration * dt, v0 + model.max_acceleration * dt)

    omega =
      omega
      |> clamp(-model.max_turn_rate, model.max_turn_rate)
      |> clamp(omega0 - max_alpha * dt, omega0 + max_alpha * dt)

    omega =
      case max_curvature do
        :infinity -> omega
        k -> clamp(omega, -abs(v) * k, abs(v) * k)
      end

    {v / 1, omega / 1}
  end

  @doc false
  @spec clamp(number(), number(), number()) :: number()
  def clamp(x, lo, hi), do: x |> max(lo) |> min(hi)

  @doc false
  # A model struct of `module` with every field a required positive
  # parameter of `kinematics`.
  @spec build!(module(), map(), atom()) :: struct()
  def build!(module, kinematics, type) do
    fields = module.__struct__() |> Map.from_struct() |> Map.keys()
    struct!(module, for(key <- fields, do: {key, fetch!(kinematics, key, type)}))
  end

  @doc false
  # A required positive parameter of `kinematics`, as a float.
  @spec fetch!(map(), atom(), atom()) :: float()
  def fetch!(kinematics, key, type) do
    case Map.get(kinematics, key) do
      x when is_number(x) and x > 0 ->
        x / 1

      other ->
        raise ArgumentError,
              "kinematics: a #{type} drive needs #{key}: a positive number, got #{inspect(other)}"
    end
  end
end
