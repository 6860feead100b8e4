defmodule ThinkingCap.Tuples do
  # The vocabulary: {tag, id, payload, written by, read by}. The id is the
  # robot's but for :door and :timing; the payload says the keys a writer
  # puts there (the typespecs below say their types).
  @vocabulary [
    {:robot, :robot,
     "the robot's capabilities (`ThinkingCap.Robot.capabilities/1`): " <>
       "`%{name:, footprint:, drive:, limits:, sensors:}`",
     "robot base (`ThinkingCap.Robot`), at start", "dashboard, rosbridge"},
    {:drive, :robot, "`%{command: command}`: what the base is to drive",
     "control (Blender, VehicleDrive, WallFollower, Wanderer)",
     "robot base, `Sim.LockstepController`"},
    {:teleop, :robot,
     "`%{command: {:velocity, v, w}, by:, sent_at:}` (refreshed within the deadman " <>
       "timeout), or `%{command: :release, by:}`", "dashboard, rosbridge",
     "robot base, rosbridge"},
    {:estop, :robot,
     "`%{engaged: boolean, by:, at: epoch_ms}`, written by `estop_engaged/3` and " <>
       "`estop_released/3` only (key `{:estop, robot}`)",
     "dashboard (and its E-stop listener), console, supervision warden", "robot base"},
    {:control, :robot,
     "`%{mode: :estop \\| :teleop \\| :autonomy \\| :idle, command:, teleop_by:, teleop_sent_at:}`: " <>
       "who drives and the command applied", "robot base", "dashboard, rosbridge, benchmarks"},
    {:driven, :robot, "`%{command:, count:}`: what a test robot drove",
     "`ThinkingCap.Testing.Robot`", "tests"},
    {:sim_pose, :robot, "`%{pose: {x, y, θ}, stamp: t}`: the simulated robot's true pose",
     "simulator", "dashboard, `mix tc.run`, benchmarks"},
    {:sim_walkers, :world,
     "`%{walkers: [{x, y, radius}], stamp: t}`: the people walking in a simulated world " <>
       "(the id is the world's name)", "simulator (`Sim.Fleet`)", "dashboard"},
    {:lps, :robot, "a `%ThinkingCap.Perception.LPS{}`: the Local Perceptual Space",
     "perception (`Perception.Fuser`)", "Blender, VehicleDrive, Monitor, WallFollower"},
    {:pose, :robot,
     "`%{pose: {x, y, θ}, covariance:, stamp:}` and, by localizer, `confidence:`, " <>
       "`status:`, `frame:` (MCL) or `beacons_used:` (EKF)", "localization (Localizer, MCL)",
     "Fuser, Mapper, Monitor, Blender, VehicleDrive, dashboard, rosbridge"},
    {:particles, :robot, "`%{poses: [{x, y, θ}], stamp: t}`", "MCL", "dashboard"},
    {:map, :robot, "a `%ThinkingCap.Navigation.OccupancyGrid{}`: the map learned", "Mapper",
     "MCL, Monitor, dashboard, rosbridge"},
    {:topology, :robot, "a `%ThinkingCap.Navigation.Topology{}`: rooms, corridors, doors",
     "Mapper", "Monitor, dashboard"},
    {:segments, :robot, "`%{segments: [{{x1, y1}, {x2, y2}, degree}], stamp: t}`", "Mapper",
     "dashboard"},
    {:map_correction, :robot, "`%{from: pose, to: pose, frame: n, map: map, stamp: t}`",
     "Mapper (a loop closed)", "MCL"},
    {:save_map, :robot, "`%{path: path}`: save the map there now", "Monitor", "Mapper"},
    {:map_saved, :robot, "`%{path: path, result: :ok \\| {:error, reason}}`", "Mapper",
     "benchmarks, tests"},
    {:plan, :robot,
     "`%{task:, state:, waypoint:, goal:, heading:, docking:, path:, door:, closed_doors:, " <>
       "replans:, recoveries:, reached:, given_up:, reason:, source:, planning:, planned_at:}` " <>
       "(`ThinkingCap.Planner.Monitor`)", "Monitor",
     "Blender, VehicleDrive, dashboard, benchmarks"},
    {:task, :robot, "`%{task: task}`, e.g. `{:go_to, place}`", "dashboard, rosbridge", "Monitor"},
    {:door, :door, "`%{open: boolean, stamp: t}`: a door seen (the id is the door's name)",
     "Monitor", "dashboard"},
    {:activation, :robot, "`%{behaviour => degree}`", "Blender", "dashboard, benchmarks"},
    {:vehicle, :robot, "`%{state:, path:, goal:, docking_error:}`", "VehicleDrive",
     "dashboard, benchmarks"},
    {:param, :robot,
     "`%{module:, key:, value:, by:, at: epoch_ms}`: a live parameter change " <>
       "(key `{:param, robot, module, key}`)", "runtime (`Runtime.Host`, `Testing.Lockstep`)",
     "dashboard, tests"},
    {:module_gave_up, :robot,
     "`%{module:, layer:, node:, reason:, restarts:, seconds:, stopped:, at:}` " <>
       "(key `{:module_gave_up, robot, module}`)", "supervision warden",
     "dashboard, console, `Runtime.resume/1`"},
    {:adf, :robot,
     "`%{node:, file:, rdf:, wdf:, dashboard:, record:, black_box:, modules:}`: an ADF started",
     "runtime", "dashboard launcher, black-box launcher"},
    {:black_box_request, :robot,
     "`%{reason:, by:, at: epoch_ms}`: dump the robot's black box now (key `{:black_box_request, robot}`)",
     "console, dashboard", "black box (`ThinkingCap.BlackBox.RingBuffer`)"},
    {:black_box_dump, :robot,
     "`%{path:, reason:, reasons:, from: epoch_ms, to: epoch_ms, messages:, node:}`: " <>
       "a black-box dump written (key `{:black_box_dump, robot}`)", "black box",
     "dashboard, console"},
    {:cluster, :robot,
     "`%{node:, logical:, up:, missing:, unplaced:}` (key `{:cluster, robot, node}`)",
     "deployment", "dashboard"},
    {:timing, :activity, "an activity's timing statistics (the id is the activity's name)",
     "`ThinkingCap.Cycle`", "dashboard"}
  ]

  @tags for {tag, _, _, _, _} <- @vocabulary, do: tag

  @moduledoc """
  The tuple vocabulary: every tuple that crosses an app boundary on the
  blackboard is built and matched through this module, so that a misspelt
  tag is a compile error (`Tuples.estp(robot, payload)` is an undefined
  macro) rather than a tuple nobody reads.

  Blackboard tuples are `{tag, id, payload}`: the id is the robot's (or,
  for a few tags, an activity's or a door's name), the payload a map or a
  struct. For each tag there is one macro, named after the tag, in two
  forms:

    * **the tuple**, `Tuples.estop(robot, payload)`, expands to
      `{:estop, robot, payload}`. It is a plain tuple, so it works as an
      expression and in a pattern alike (as `Record` does): in a function
      head, a `case` clause, a `for` generator, `match?/2`.

          def handle_tuple(Tuples.drive(robot, %{command: c}), %{robot: robot} = s), do: ...
          Blackboard.out(Tuples.drive(robot, %{command: :stop}))

    * **the template**, the same name without the payload:
      `Tuples.estop(robot)` expands to `{:estop, robot, :_}` and
      `Tuples.estop()` to `{:estop, :_, :_}` (every robot's), for
      `subscribe`, `rd`, `rd_all`, `takep` and the `subscribe:` action.
      A template is not a pattern (it would match only a payload that is
      the atom `:_`): used in a pattern it is a compile error that says
      to give the payload.

  A sensor's readings are tagged with the sensor's name in the RDF, so
  they have one macro with the name as its first argument:
  `Tuples.reading(:laser, robot, scan)`, template
  `Tuples.reading(:laser, robot)`.

  Writers of latest-value tuples give the blackboard a key; `key/1` is
  the one convention (`{tag, id}`, and per module and param for the few
  tags that keep more than one per robot) and `keyed/1` the
  `{tuple, [key: key]}` an `:out` action takes. `tag/1` checks a tag
  named on its own (a list of streams) at compile time. `estop_engaged/3`
  and `estop_released/3` are the one way to write an E-stop.

  Use it with `require ThinkingCap.Tuples` (and an `alias`), or `import
  ThinkingCap.Tuples, only: [...]`.

  ## The tags

  | tag | id | payload | written by | read by |
  |---|---|---|---|---|
  #{Enum.map_join(@vocabulary, "\n", fn {tag, id, payload, writer, reader} -> "| `#{inspect(tag)}` | #{id} | #{payload} | #{writer} | #{reader} |" end)}
  | a sensor's name | robot | a reading (`%{ranges: ...}`, `%{pose: ...}`, ...) | robot base, simulator | perception, localization, mapping, dashboard, rosbridge |
  """

  @typedoc "A robot's id: the ADF's `robot:`."
  @type robot :: atom()

  @typedoc "A template: a tuple with `:_` wildcards (`ThinkingCap.Blackboard.Template`)."
  @type template :: {atom(), term(), :_}

  @typedoc "A command a robot base drives (`ThinkingCap.Robot.command/0`)."
  @type command :: term()

  @type robot_info ::
          {:robot, robot(),
           %{name: term(), footprint: term(), drive: atom(), limits: map(), sensors: [map()]}}
  @type drive :: {:drive, robot(), %{command: command()}}
  @type teleop ::
          {:teleop, robot(),
           %{
             required(:command) => command() | :release,
             required(:by) => term(),
             optional(:sent_at) => number() | nil
           }}
  @type estop_payload :: %{
          required(:engaged) => boolean(),
          required(:by) => term(),
          required(:at) => integer()
        }
  @type estop :: {:estop, robot(), estop_payload()}
  @type control ::
          {:control, robot(),
           %{
             mode: :estop | :teleop | :autonomy | :idle,
             command: command() | nil,
             teleop_by: term(),
             teleop_sent_at: term()
           }}
  @type driven :: {:driven, robot(), %{command: command(), count: pos_integer()}}
  @type sim_pose :: {:sim_pose, robot(), %{pose: {float(), float(), float()}, stamp: float()}}
  @type sim_walkers ::
          {:sim_walkers, term(), %{walkers: [{float(), float(), float()}], stamp: float()}}
  @type reading :: {atom(), robot(), map()}
  @type lps :: {:lps, robot(), struct()}
  @type pose ::
          {:pose, robot(),
           %{required(:pose) => {float(), float(), float()}, optional(atom()) => term()}}
  @type particles ::
          {:particles, robot(), %{poses: [{float(), float(), float()}], stamp: float()}}
  @type learned_map :: {:map, robot(), struct()}
  @type topology :: {:topology, robot(), struct()}
  @type segments ::
          {:segments, robot(),
           %{segments: [{{float(), float()}, {float(), float()}, float()}], stamp: float()}}
  @type map_correction ::
          {:map_correction, robot(),
           %{from: tuple(), to: tuple(), frame: non_neg_integer(), map: struct(), stamp: float()}}
  @type save_map :: {:save_map, robot(), %{path: Path.t()}}
  @type map_saved :: {:map_saved, robot(), %{path: Path.t(), result: :ok | {:error, term()}}}
  @type plan :: {:plan, robot(), map()}
  @type task :: {:task, robot(), %{task: term()}}
  @type door :: {:door, atom(), %{open: boolean(), stamp: float()}}
  @type activation :: {:activation, robot(), %{atom() => float()}}
  @type vehicle ::
          {:vehicle, robot(), %{state: atom(), path: term(), goal: term(), docking_error: term()}}
  @type param ::
          {:param, robot(),
           %{module: atom(), key: atom(), value: term(), by: term(), at: integer()}}
  @type module_gave_up ::
          {:module_gave_up, robot(),
           %{
             module: atom() | nil,
             layer: atom(),
             node: node(),
             reason: String.t(),
             restarts: non_neg_integer(),
             seconds: pos_integer(),
             stopped: [atom()],
             at: integer()
           }}
  @type adf ::
          {:adf, robot(),
           %{
             node: node(),
             file: Path.t() | nil,
             rdf: Path.t() | nil,
             wdf: Path.t() | nil,
             dashboard: term(),
             record: map(),
             black_box: map(),
             modules: [atom()]
           }}
  @type black_box_request ::
          {:black_box_request, robot(), %{reason: String.t() | atom(), by: term(), at: integer()}}
  @type black_box_dump ::
          {:black_box_dump, robot(),
           %{
             path: Path.t(),
             reason: String.t(),
             reasons: [String.t()],
             from: integer(),
             to: integer(),
             messages: non_neg_integer(),
             node: node()
           }}
  @type cluster ::
          {:cluster, robot(),
           %{node: node(), logical: atom(), up: [atom()], missing: [atom()], unplaced: [atom()]}}
  @type timing :: {:timing, atom(), map()}

  @typedoc "Every tuple of the vocabulary."
  @type t ::
          robot_info()
          | drive()
          | teleop()
          | estop()
          | control()
          | driven()
          | sim_pose()
          | sim_walkers()
          | reading()
          | lps()
          | pose()
          | particles()
          | learned_map()
          | topology()
          | segments()
          | map_correction()
          | save_map()
          | map_saved()
          | plan()
          | task()
          | door()
          | activation()
          | vehicle()
          | param()
          | module_gave_up()
          | adf()
          | black_box_request()
          | black_box_dump()
          | cluster()
          | timing()

  ## The constructors and templates

  for {tag, id, payload, writer, reader} <- @vocabulary do
    id_var = Macro.var(id, nil)

    @doc """
    `{#{inspect(tag)}, #{id}, payload}`, as an expression or a pattern.

    Payload: #{payload}.

    Written by #{writer}; read by #{reader}.
    """
    defmacro unquote(tag)(unquote(id_var), payload),
      do: tuple(unquote(tag), unquote(id_var), payload)

    @doc """
    The template `{#{inspect(tag)}, #{id}, :_}` (`#{id}` defaults to `:_`, every
    #{id}'s): for subscriptions and reads, not for patterns.
    """
    defmacro unquote(tag)(unquote(id_var) \\ :_),
      do: template(unquote(tag), unquote(id_var), __CALLER__)
  end

  @doc """
  `{sensor, robot, payload}`: a reading of the robot's sensor named
  `sensor` in its RDF (`:laser`, `:odom`, `:bumper`, ...), as an
  expression or a pattern. Robot bases (and the simulator) write them,
  latest value, key `{sensor, robot}`.
  """
  defmacro reading(sensor, robot, payload), do: tuple(sensor, robot, payload)

  @doc """
  The template `{sensor, robot, :_}` (`robot` defaults to `:_`): for
  subscriptions and reads, not for patterns.
  """
  defmacro reading(sensor, robot \\ :_), do: template(sensor, robot, __CALLER__)

  @doc """
  `tag` itself, checked at compile time: a tag of the vocabulary (a list
  of streams to follow, say), or a compile error.

      @streams [Tuples.tag(:pose), Tuples.tag(:plan)]
  """
  defmacro tag(tag) when tag in @tags, do: tag

  defmacro tag(tag) do
    raise CompileError,
      file: __CALLER__.file,
      line: __CALLER__.line,
      description:
        "#{Macro.to_string(tag)} is not a tag of ThinkingCap.Tuples " <>
          "(one of #{Enum.map_join(@tags, ", ", &inspect/1)})"
  end

  @doc "The tags of the vocabulary (not the sensors' names, which the RDF gives)."
  @spec tags() :: [atom()]
  def tags, do: @tags

  @doc """
  The blackboard key a writer gives a tuple so that the latest one stays:
  `{tag, id}`, except `{:param, robot, module, key}` (the latest per
  param), `{:module_gave_up, robot, module}` and `{:cluster, robot, node}`
  (one per node).
  """
  @spec key(tuple()) :: tuple()
  def key({:param, robot, %{module: module, key: key}}), do: {:param, robot, module, key}
  def key({:module_gave_up, robot, %{module: module}}), do: {:module_gave_up, robot, module}
  def key({:cluster, robot, %{node: node}}), do: {:cluster, robot, node}
  def key({tag, id, _payload}), do: {tag, id}

  @doc """
  `{tuple, [key: key(tuple)]}`: what an `:out` action takes to write a
  latest-value tuple (`out: Tuples.keyed(Tuples.drive(robot, %{command: c}))`).
  """
  @spec keyed(tuple()) :: {tuple(), keyword()}
  def keyed(tuple), do: {tuple, [key: key(tuple)]}

  @doc """
  The E-stop engaged by `by` (a person, `:console`, the runtime), at
  `at` (epoch ms, default now): the one way to write one.
  """
  @spec estop_engaged(robot(), term(), integer()) :: estop()
  def estop_engaged(robot, by, at \\ System.os_time(:millisecond)),
    do: {:estop, robot, %{engaged: true, by: by, at: at}}

  @doc "The E-stop released by `by`, at `at` (epoch ms, default now)."
  @spec estop_released(robot(), term(), integer()) :: estop()
  def estop_released(robot, by, at \\ System.os_time(:millisecond)),
    do: {:estop, robot, %{engaged: false, by: by, at: at}}

  defp tuple(tag, id, payload), do: {:{}, [], [tag, id, payload]}

  defp template(tag, id, caller) do
    if Macro.Env.in_match?(caller) do
      raise CompileError,
        file: caller.file,
        line: caller.line,
        description:
          "a ThinkingCap.Tuples template ({#{Macro.to_string(tag)}, #{Macro.to_string(id)}, :_}) " <>
            "is not a pattern: give the payload (a pattern, or _) as the last argument"
    end

    {:{}, [], [tag, id, :_]}
  end
end
