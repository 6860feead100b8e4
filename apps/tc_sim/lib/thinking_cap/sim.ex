defmodule ThinkingCap.Sim do
  @moduledoc """
  The simulator: a world (`ThinkingCap.Sim.World`, from a WDF) and the
  robots in it, stepped on a simulation clock.

      {:ok, sim} = ThinkingCap.Sim.start_link(world: "priv/examples/office.wdf", mode: :fast, seed: 7)
      :ok = ThinkingCap.Sim.add_robot(sim, :r1, rdf: "priv/examples/office_robot.rdf", at: :dock,
                                      controller: {ThinkingCap.Sim.Wander, []})
      :ok = ThinkingCap.Sim.run_for(sim, 60.0)
      ThinkingCap.Sim.pose(sim, :r1)

  ## Clock and modes

  Time advances in steps of `step` seconds (default 0.01). In `:realtime`
  mode the timing worker (`ThinkingCap.Cycle`) releases every step, so
  simulated time keeps pace with the wall clock; a step that is still
  running when the next release comes makes the simulation fall behind,
  and `status/1` counts those `lagged` releases. In `:fast` mode steps
  follow each other as fast as the machine allows. Either way the
  simulation can be paused, stepped by hand (`step/2`), run for a stretch
  of simulated time (`run_for/2`) and reset to its start.

  ## Each step

  Every robot moves by its kinematics and odometry error model
  (`ThinkingCap.Robot.Kinematics`, `ThinkingCap.Robot.OdometryError`) under
  its current command; a move into an obstacle (a wall, a closed door, an
  occupied map cell, another robot or a walker) is refused and closes the
  bumper. Walkers (`add_walker/3`) then take their step.
  Then each sensor due at this step reads (its `rate` from the RDF), seeing
  the world, the other robots (as discs of their footprint radius) and
  the walkers where they stand after this step's moves: a reading and the
  true poses of its stamp agree. Robots are stepped in parallel, in
  shards of 16 robots spread over the schedulers (see `:shards`), regrouped
  by place now and then so that a shard's rays stay in one part of the
  map; moves that ran two robots into each other are taken back (both
  stay where they were, bumpers pressed), so robots never overlap.

  Readings are `{sensor, payload}` pairs (payloads below) and go:

    * to the robot's in-process controller (`ThinkingCap.Sim.Controller`),
      if it has one: its `control/2` answers with the next command;
    * to the robot's owner process, if it has one (the
      `ThinkingCap.Sim.Robot` driver of an ADF), as
      `{:tc_sim, :readings, robot, readings}`;
    * to the blackboard as `{sensor, robot, payload}` latest-value tuples
      (key `{sensor, robot}`) when the simulation was started with
      `publish: true`.

  Every 0.1 s of simulated time the readings include the true pose,
  `{:sim_pose, %{pose: {x, y, theta}, stamp: t}}`.

  ## Payloads

    * sonar: `%{ranges: [m], headings: [rad], range_min:, range_max:, stamp:}`
      (headings of the transducers in the robot frame);
    * laser: `%{ranges: [m], angle_min:, angle_max:, angle_increment:,
      range_min:, range_max:, stamp:}` (angles relative to the laser, as in
      ROS `sensor_msgs/LaserScan`; no echo reads `range_max`);
    * beacon_laser: `%{detections: [%{id: name, range: m, bearing: rad}], stamp:}`;
    * bumper: `%{pressed: boolean, stamp:}`;
    * odometry: `%{pose: {x, y, theta}, twist: {v, omega}, stamp:}` (the
      odometry frame starts at the robot's start pose, as `{0, 0, 0}`).

  An in-process controller that takes packed ranges
  (`c:ThinkingCap.Sim.Controller.packed_ranges?/0`, as
  `ThinkingCap.Sim.Wander` does) gets a sonar's or laser's `ranges` as a
  binary of little-endian float64s, the same values, unless that sensor's
  readings also go to the blackboard.

  ## Determinism

  With in-process controllers (or none), a run in `:fast` mode is
  determined by the `seed`: every random draw (noise, faults, slip,
  controllers) comes from a per-robot state seeded from it, and every
  robot of a step sees the world as it was at the step's start, whatever
  the number of shards, how robots are split over them and the number of
  schedulers.
  """

  alias ThinkingCap.Sim.Core.Server

  @type sim :: GenServer.server()
  @type robot :: atom()

  @doc """
  Starts a simulation. Options:

    * `:world` - a WDF path, a `ThinkingCap.Config.WDF` or a built
      `ThinkingCap.Sim.World` (required);
    * `:mode` - `:realtime` (default) or `:fast`;
    * `:step` - seconds per step (default 0.01);
    * `:speed` - in `:realtime` mode, simulated seconds per wall second
      (default 1.0): a step is released every `step / speed` seconds, so
      a machine that cannot keep a large fleet in real time can run it
      slower (the ADF's periods must then be scaled by the same factor);
    * `:seed` - integer (default 1);
    * `:running` - start stepping at once (default `true`; `:fast` mode
      with `running: false` waits for `run_for/2` or `step/2`);
    * `:publish` - publish readings on the blackboard (default `false`);
    * `:shards` - processes stepping robots at the start (default: the
      schedulers online); as many again start when each holds
      `:per_shard` robots (default 16). The split changes nothing in the
      results, only how evenly the work spreads over the cores;
    * `:regroup_every` - steps between two regroupings of the robots by
      place (default 50): robots near each other move to the same shard,
      whose rays then stay in one part of the map (faster in large
      worlds). A robot moved hands its whole state over, controller's
      included;
    * `:walkers` - people walking in the world: `[{id, opts}]` as
      `add_walker/3`;
    * `:nodes` - spread the robots over these BEAM nodes (connected,
      each with this code; see "Across nodes" below); `:shards` is then
      per node (default: each node's schedulers);
    * `:borders` - across nodes, the `length(nodes) - 1` ascending x
      coordinates between their regions (default: the world's width cut
      evenly);
    * `:name` - a name to register.

  ## Across nodes

  With `nodes: [a, b, ...]` the world is cut along x into strips, one
  per node, between `borders`. Each node builds its own copy of the
  static world (from the WDF: give `world:` as a WDF path that every
  node can read, or a `ThinkingCap.Config.WDF`) and runs the shards of
  the robots in its strip. This process stays the coordinator, and the
  step keeps its two phases in lock-step: before the moves it sends each
  node the bodies it must see, its own robots and the ghosts, every
  robot of another region and every walker within sensor reach of its
  robots (the longest sensor range of any robot, plus its footprint and
  a margin for the step's move); the contacts among the moves and the
  walkers' step are found here; then each node gets the bodies it must
  see where they stand after the moves, and every shard senses. When the robots
  are regrouped (`:regroup_every`), a robot now in another node's strip
  is handed over to a shard of that node whole: body, sensors, random
  state and controller state (an owner pid works from any node). Body
  indexes are the coordinator's and every random draw is the robot's
  own, so a run across nodes equals the one-node run with the same seed.
  `placement/1` tells where each robot runs; `status/1` counts the
  `node_handovers` and the last step's `ghosts`. A node that goes down
  takes the simulation down with it (the regions are linked to it).
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts), do: Server.start_link(opts)

  @doc """
  Starts a simulation as `start_link/1` does, not linked to the caller
  (started by a remote call, whose process ends at once). Stop it with
  `GenServer.stop/1`.
  """
  @spec start(keyword()) :: GenServer.on_start()
  def start(opts), do: Server.start(opts)

  @doc """
  Adds a robot. Options:

    * `:rdf` (a path) or `:description` (a `ThinkingCap.Robot.Description`) - required;
    * `:at` - start pose `{x, y, theta}`, point `{x, y}` or waypoint name (required);
    * `:controller` - `{module, args}` of a `ThinkingCap.Sim.Controller`, or
    * `:owner` - a pid that gets the readings and sends commands (`command/3`);
    * `:seed` - the robot's own seed (default: derived from the simulation's);
    * `:publish` - sensor names (`:sim_pose` too) whose readings go to the
      blackboard even when the simulation does not publish (default `[]`):
      a fleet shown on the dashboard by its true poses alone.

  Refused when the id is taken or the start pose is not free.
  """
  @spec add_robot(sim(), robot(), keyword()) :: :ok | {:error, String.t()}
  def add_robot(sim, id, opts), do: GenServer.call(sim, {:add_robot, id, opts}, 30_000)

  @doc "The node each robot runs on (`:nodes`; every robot on this node otherwise)."
  @spec placement(sim()) :: %{robot() => node()}
  def placement(sim), do: GenServer.call(sim, :placement)

  @doc "Removes a robot."
  @spec remove_robot(sim(), robot()) :: :ok | {:error, :no_robot}
  def remove_robot(sim, id), do: GenServer.call(sim, {:remove_robot, id})

  @doc "Makes `owner` the process that gets a robot's readings (a restarted driver)."
  @spec attach(sim(), robot(), pid()) :: :ok | {:error, :no_robot}
  def attach(sim, id, owner) when is_pid(owner), do: GenServer.call(sim, {:attach, id, owner})

  @doc """
  Sets the command a robot follows (`t:ThinkingCap.Robot.command/0`) from
  the next step on. Robots with an in-process controller are commanded by
  it.
  """
  @spec command(sim(), robot(), ThinkingCap.Robot.command()) :: :ok
  def command(sim, id, command), do: GenServer.cast(sim, {:command, id, command})

  @doc "Opens or closes a door of the world while running."
  @spec set_door(sim(), atom(), boolean()) :: :ok | {:error, String.t()}
  def set_door(sim, door, open?), do: GenServer.call(sim, {:set_door, door, open?})

  @doc "Stops the clock."
  @spec pause(sim()) :: :ok
  def pause(sim), do: GenServer.call(sim, :pause)

  @doc "Starts the clock again."
  @spec resume(sim()) :: :ok
  def resume(sim), do: GenServer.call(sim, :resume)

  @doc "Runs `n` steps now (single-stepping a paused simulation); returns when done."
  @spec step(sim(), pos_integer()) :: :ok
  def step(sim, n \\ 1), do: GenServer.call(sim, {:run_steps, n}, :infinity)

  @doc "Runs `seconds` of simulated time as fast as possible; returns when done."
  @spec run_for(sim(), number()) :: :ok
  def run_for(sim, seconds), do: GenServer.call(sim, {:run_for, seconds}, :infinity)

  @doc "Puts every robot back at its start, the doors as the WDF has them, and the clock at 0."
  @spec reset(sim()) :: :ok
  def reset(sim), do: GenServer.call(sim, :reset, 30_000)

  @doc "Simulated seconds since the start (or the last reset)."
  @spec time(sim()) :: float()
  def time(sim), do: GenServer.call(sim, :time)

  @doc "A robot's true pose."
  @spec pose(sim(), robot()) :: {:ok, {float(), float(), float()}} | {:error, :no_robot}
  def pose(sim, id), do: GenServer.call(sim, {:get, id, :pose})

  @doc """
  Adds a walker: a person, a disc of `radius` (default 0.25 m) walking
  `route` (a list of two points or waypoint names or more) at `speed`
  (default 0.8 m/s), back and forth, or round with `loop: true`. Every
  sensor sees walkers as it sees robots, a robot moving into one is
  stopped (its bumper pressed), and a walker waits while its next step
  would touch a robot or another walker. Deterministic: walkers draw no
  random numbers.
  """
  @spec add_walker(sim(), term(), keyword()) :: :ok | {:error, String.t()}
  def add_walker(sim, id, opts), do: GenServer.call(sim, {:add_walker, id, opts})

  @doc "Removes a walker."
  @spec remove_walker(sim(), term()) :: :ok | {:error, :no_walker}
  def remove_walker(sim, id), do: GenServer.call(sim, {:remove_walker, id})

  @doc "The walkers and where they stand."
  @spec walkers(sim()) :: %{term() => {float(), float()}}
  def walkers(sim), do: GenServer.call(sim, :walkers)

  @doc "The walkers as discs `{x, y, radius}`, in order of id."
  @spec walker_discs(sim()) :: [{float(), float(), float()}]
  def walker_discs(sim), do: GenServer.call(sim, :walker_discs)

  @doc """
  Moves a robot to `pose` (a point, a pose or a waypoint's name) without
  its knowing: its odometry carries on from where it was, as when a robot
  is carried away (a kidnapping). Refused if the robot would overlap
  something there.
  """
  @spec teleport(sim(), robot(), atom() | {number(), number()} | {number(), number(), number()}) ::
          :ok | {:error, :no_robot | String.t()}
  def teleport(sim, id, pose), do: GenServer.call(sim, {:teleport, id, pose})

  @doc "A robot's odometry pose (where its encoders think it is, from `{0, 0, 0}`)."
  @spec odometry(sim(), robot()) :: {:ok, {float(), float(), float()}} | {:error, :no_robot}
  def odometry(sim, id), do: GenServer.call(sim, {:get, id, :odom})

  @doc "The state of a robot's in-process controller (to look inside in tests and benchmarks)."
  @spec controller_state(sim(), robot()) :: {:ok, term()} | {:error, :no_robot}
  def controller_state(sim, id), do: GenServer.call(sim, {:get, id, :cstate})

  @doc """
  Changes the state of a robot's in-process controller with `fun` (tests
  use it to hand a `ThinkingCap.Sim.LockstepController` a tuple, such as a
  new task, between steps).
  """
  @spec update_controller(sim(), robot(), (term() -> term())) :: :ok | {:error, :no_robot}
  def update_controller(sim, id, fun) when is_function(fun, 1),
    do: GenServer.call(sim, {:update_cstate, id, fun})

  @doc "The robots and their true poses."
  @spec robots(sim()) :: %{robot() => {float(), float(), float()}}
  def robots(sim), do: GenServer.call(sim, :robots)

  @doc "The world as it is now (doors open or closed)."
  @spec world(sim()) :: ThinkingCap.Sim.World.t()
  def world(sim), do: GenServer.call(sim, :world)

  @doc """
  The clock (`time`, `steps`, `step`, `speed`, `mode`, `running`, `lagged`
  releases in real-time mode), `robots`, `walkers`, `shards`, `nodes`,
  `node_handovers` and `ghosts` (see "Across nodes"), `handovers`
  (robots moved from one shard to another, see `:regroup_every`), `rays`
  cast (primary rays: cone rays and beams, bounces not counted) and
  `blocked` robot-steps (moves refused because of a contact).
  """
  @spec status(sim()) :: map()
  def status(sim), do: GenServer.call(sim, :status)
end
