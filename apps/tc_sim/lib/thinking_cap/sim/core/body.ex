defmodule ThinkingCap.Sim.Core.Body do
  @moduledoc false
  # One simulated robot: its true pose, its odometry, the command it
  # follows, its sensors and where its readings go. A step moves it (the
  # kinematics with the odometry error model, refusing moves into
  # obstacles), reads the sensors that are due and runs its in-process
  # controller, if it has one. Everything random draws from the robot's own
  # seeded state, so a run does not depend on how robots are spread over
  # processes.

  alias ThinkingCap.Robot.{Kinematics, OdometryError}
  alias ThinkingCap.Sim.Core.Sensors

  @doc "A robot at its start pose. `spec` is what `ThinkingCap.Sim.add_robot/3` was given."
  def new(spec, dt) do
    d = spec.description
    rng = :rand.seed_s(:exsss, {spec.seed, spec.index, 1})
    {sensors, rng} = Sensors.setup(d.sensors, dt, rng)

    {sink, cstate} =
      case spec.sink do
        {:controller, module, args} ->
          {{:controller, module}, module.init(args, %{robot: spec.id, description: d})}

        other ->
          {other, nil}
      end

    packed =
      case sink do
        {:controller, module} -> ThinkingCap.Sim.Controller.packed_ranges?(module)
        _ -> false
      end

    %{
      id: spec.id,
      index: spec.index,
      spec: spec,
      model: d.kinematics,
      radius: d.footprint.radius * 1.0,
      # discs covering the footprint, {x, y, r} in the robot frame
      circles: (Map.get(d, :circles) || []) |> covering(d.footprint.radius),
      pose: spec.pose,
      odom: {0.0, 0.0, 0.0},
      odom_twist: {0.0, 0.0},
      twist: {0.0, 0.0},
      command: :stop,
      bumped: false,
      err: OdometryError.new(d.kinematics, d.odometry_error, spec.seed * 7919 + spec.index),
      rng: rng,
      sensors: sensors,
      sink: sink,
      # the readings published on the blackboard whatever the simulation's
      # publish: option (a fleet shown on the dashboard by its poses)
      publish: Map.get(spec, :publish, MapSet.new()),
      cstate: cstate,
      # the controller takes ranges as binaries (Sim.Controller)
      packed: packed,
      rays: 0
    }
  end

  @doc "Sets the command the robot follows from the next step on."
  def command(body, command), do: %{body | command: command}

  @doc "Moves the robot by one step of `dt` seconds."
  def move(body, world, dt) do
    wanted = twist(body.model, body.command)
    twist = Kinematics.limit(body.model, wanted, body.twist, dt)
    {true_twist, odom_twist, err} = OdometryError.step(body.err, twist, dt)
    pose = Kinematics.integrate(body.pose, true_twist, dt)

    case discs_free(body.circles, world, body, pose, false) do
      {:free, touching} ->
        %{
          body
          | pose: pose,
            odom: Kinematics.integrate(body.odom, odom_twist, dt),
            odom_twist: odom_twist,
            twist: twist,
            err: err,
            bumped: touching
        }

      :blocked ->
        # blocked: the bumper closes and the robot stops where it is
        %{body | twist: {0.0, 0.0}, odom_twist: {0.0, 0.0}, err: err, bumped: true}
    end
  end

  # Each disc of the footprint at `pose` clear, or at least no nearer an
  # obstacle than it was (so a robot that touches may back away):
  # `{:free, touching}`, touching when a disc touches; else `:blocked`.
  # (Recursion, not closures: this runs for every robot at every step.)
  defp discs_free([], _world, _body, _pose, touching), do: {:free, touching}

  defp discs_free([{cx, cy, r} | rest], world, body, pose, touching) do
    c = clearance(world, body, at(pose, cx, cy))

    if c >= r or c >= clearance(world, body, at(body.pose, cx, cy)),
      do: discs_free(rest, world, body, pose, touching or c < r),
      else: :blocked
  end

  @doc """
  Takes back a move (`moved` is `before` moved by `move/3`): the robot
  stays where it was, blocked, as when `move/3` refuses the move.
  """
  def block(before, moved),
    do: %{before | twist: {0.0, 0.0}, odom_twist: {0.0, 0.0}, err: moved.err, bumped: true}

  defp covering([], radius), do: [{0.0, 0.0, radius * 1.0}]
  defp covering(circles, _radius), do: circles

  # a point of the robot frame in the world
  defp at({x, y, theta}, cx, cy) do
    {c, s} = {:math.cos(theta), :math.sin(theta)}
    {x + c * cx - s * cy, y + s * cx + c * cy}
  end

  defp clearance(world, body, {x, y}),
    do: ThinkingCap.Sim.Raycast.clearance(world.raycast, x, y, body.index, body.radius * 2)

  @doc """
  Reads the sensors due at `step`; returns `{readings, body}` with readings
  a list of `{sensor, payload}`. `publish` tells whether every reading
  goes to the blackboard (those of `body.publish` always do): their
  ranges are lists, whatever the controller takes.
  """
  def sense(body, world, step, time, seed, publish \\ false) do
    packed = body.packed and match?({:controller, _}, body.sink) and not publish
    at = {body, world, step, time, seed, packed}
    {sensors, readings, rays, rng} = sense_each(body.sensors, at, [], [], 0, body.rng)
    {readings, %{body | sensors: sensors, rng: rng, rays: rays}}
  end

  # the sensors in order, each read when due (recursion, not a closure:
  # this runs for every robot at every step)
  defp sense_each([], _at, sensors, readings, rays, rng),
    do: {:lists.reverse(sensors), :lists.reverse(readings), rays, rng}

  defp sense_each([sensor | rest], at, sensors, readings, rays, rng) do
    {body, world, step, time, seed, packed} = at

    if Sensors.due?(sensor, step) do
      scan_seed = :erlang.phash2({seed, body.index, step, sensor.index}, 4_294_967_296)
      packed = packed and not MapSet.member?(body.publish, sensor.name)

      {payload, sensor, rng} =
        Sensors.read(sensor, %{body | rng: rng}, world, time, scan_seed, packed)

      {readings, rays} =
        if payload,
          do: {[{sensor.name, payload} | readings], rays + sensor.rays},
          else: {readings, rays}

      sense_each(rest, at, [sensor | sensors], readings, rays, rng)
    else
      sense_each(rest, at, [sensor | sensors], readings, rays, rng)
    end
  end

  @doc "Runs the in-process controller on fresh readings."
  def control(%{sink: {:controller, module}} = body, readings) when readings != [] do
    {command, cstate} = module.control(Map.new(readings), body.cstate)
    %{body | command: command, cstate: cstate}
  end

  def control(body, _readings), do: body

  # A command as the body twist it asks for.
  defp twist(_model, :stop), do: {0.0, 0.0}
  defp twist(_model, {:velocity, v, w}), do: {v * 1.0, w * 1.0}

  defp twist(model, {kind, _, _} = actuation) when kind in [:wheels, :steer],
    do: Kinematics.forward(model, actuation)
end
