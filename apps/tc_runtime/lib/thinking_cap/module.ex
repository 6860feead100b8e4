defmodule ThinkingCap.Module do
  @moduledoc """
  The behaviour of a ThinkingCap module. A module author writes callbacks
  that return `{actions, state}`; the framework owns the process, its
  supervision and restarts, its blackboard subscriptions, its placement on
  the node the ADF names, and its timing. The module author's guide,
  `docs/module_guide.md`, writes one from scratch with its params, ADF
  entry and tests (`ThinkingCap.Examples.WallFollower`).

      defmodule MyRobot.Cruise do
        use ThinkingCap.Module

        @impl true
        def init(params, _context), do: {:ok, %{speed: Keyword.get(params, :speed, 0.2)}}

        @impl true
        def handle_cycle(_release, state), do: {[command: {:vel, state.speed, 0.0}], state}

        @impl true
        def handle_tuple({:bumper, _robot, %{pressed: true}}, state), do: {[], %{state | speed: 0.0}}
        def handle_tuple(_tuple, state), do: {[], state}
      end

  The activity comes from the ADF:

    * **periodic** - `handle_cycle/2` at every release of the timing worker
      (`ThinkingCap.Cycle`); a `{:command, term}` action is the cycle's
      result. A result that misses the deadline is replaced by the ADF's
      `fallback` in that same cycle.
    * **event** - `handle_tuple/2` for every tuple matching the ADF's
      `subscribe` templates (also delivered to periodic modules).
    * **background** - `handle_background/1` again and again, at low process
      priority: it runs when nothing else does (logging, map saving).

  Actions (a list, or a keyword list; `t:action/0`):

    * `{:out, tuple}` / `{:out, {tuple, opts}}` - write to the blackboard
      (`opts` as in `ThinkingCap.Blackboard.out/2`);
    * `{:command, term}` - the result of the current cycle (periodic only);
    * `{:wire, iodata}` - with `{:command, term}` in `handle_cycle/2`: the
      bytes the timing worker puts on the module's wire when it applies
      the command;
    * `{:attach_wire, device, fallback_iodata}` - hands the device's
      command path to the timing worker (periodic only, typically from
      `init/2`: it runs once the activity is added). The worker opens
      `device` write-only (its line settings are left to whoever opened
      it), writes each applied result's `:wire` bytes, and writes
      `fallback_iodata` whenever it applies the fallback: a missed
      deadline, the module crashed or stopped, the BEAM gone. A device
      that cannot be opened is logged, naming it, and the module runs on
      without a wire;
    * `{:detach_wire}` - takes the command path back from the worker;
    * `{:subscribe, template}` - subscribe to more tuples;
    * `{:set_param, key, value}` - sets one of the module's own declared
      params (checked against its type; recorded like a live change, below,
      `by: {:module, name}`; `handle_param/3` is not called for it).

  Anything else (a misspelt `{:outt, tuple}`, an `{:out, 42}`), or a
  result that is not `{actions, state}`, raises
  `ThinkingCap.Module.ActionError` naming the module, the callback and the
  action: the module stops and its supervisor starts it again. A
  `{:command, _}` or `{:wire, _}` outside `handle_cycle/2`, or a wire
  action of a module that is not periodic, counts for nothing and is
  logged. The runtime and `ThinkingCap.Testing.Lockstep` read results with
  the same code, so a module behaves the same in both.

  Every command the timing worker applies for a periodic module, its own
  fresh result or the fallback that replaced a late one, reaches
  `handle_applied/2` (`%{cycle: n, kind: :fresh | :fallback | :late,
  command: term, wired: boolean, response_us: float, applied_ns: t | nil}`,
  see `ThinkingCap.Cycle`; a `:late` result was not applied; `wired: true`
  says the worker put the command's bytes on the module's wire, whole, and
  `false` that the module must drive the device itself). A module that drives hardware acts on these, never
  on its own results: then a stalled module leaves the robot on its
  fallback, not on a stale command.

  `init/2` gets the ADF's `params` and a context map (`:name`, `:robot`,
  `:node`, `:activity`, the ADF's `:rdf` and `:wdf` paths, `nil` when
  not given, `:handoff`, below, and `:params`, the params as they stand:
  a declared schema's fields with their defaults) and returns
  `{:ok, state}` or `{actions, state}`.

  **Declared params.** A module may implement `params/0`, the schema of
  its params (`ThinkingCap.Config.Schema` fields: type, default, doc):
  the ADF reader then checks the module's `params` against it, so that a
  misspelt key is an error with a "did you mean", a value out of range an
  error with the range, and a `:place` a name the run's WDF must hold,
  each at its file:line. `mix tc.check --explain MODULE` prints it.

      @impl true
      def params do
        [
          max_speed: {{:number_range, 0.0, 2.0}, default: 0.3, doc: "m/s"},
          goal: {:place, required: true, doc: "where to go"}
        ]
      end

  **Live parameters.** A module's declared params can be read and set
  while it runs, as ROS 2 nodes' parameters are:
  `ThinkingCap.Runtime.get_params/1` and `set_param/4`, `params/1` and
  `param/3` in a remote shell (`ThinkingCap.Console`), the dashboard's
  Params panel. A change is checked against the schema: an unknown key is
  refused with a "did you mean", a value out of range with the range, a
  value of the wrong type with the type, and a field declared
  `read_only: true` (set in the ADF, read at start: a seed, a particle
  count) is refused. The module sees an accepted change in
  `handle_param/3`, between two callbacks (a periodic module's next cycle
  runs with it), and may still refuse it with `{:error, reason, state}`
  (a refusal leaves its state as it was):

      @impl true
      def handle_param(:max_speed, value, state), do: {[], %{state | max_speed: value}}

  `handle_param/3` is optional, and not defined by `use
  ThinkingCap.Module`: **a module without it takes no live changes** (a
  change is refused saying so, and the dashboard shows its params
  read-only), since a change it would not act on must not look accepted.
  Every accepted change is written to the blackboard as
  `{:param, robot, %{module: name, key: key, value: value, by: who, at: epoch_ms}}`
  (key `{:param, robot, name, key}`: the latest per param stays), so it
  is seen and recorded. A module restarted (after a crash, or
  `ThinkingCap.Runtime.restart/1`) starts again from the ADF's params.

  **Handoff.** A module deployed with standby nodes may implement
  `handoff/1`: every `handoff_every` seconds (ADF, default 1) the framework
  calls it and sends what it returns to the deployments of the other
  nodes of the module's `[node | standby]`. When the module is started on
  one of them (a failover, a move, a failback), `init/2` finds the latest
  handoff that node received in `context.handoff` (`nil` if none), and
  can carry on from it: a localizer from its last estimate, a planner
  from the waypoint it was heading for, rather than from their start.
  When a module is replaced while running (`ThinkingCap.Runtime.swap/2`),
  the new module's `handle_swap/3` (old module, old state, context) gives
  its first state; without it, `init/2` does.

  **Replay.** While its robot is recorded, the runtime traces every
  callback of a module, what it was given and what it returned
  (`ThinkingCap.Runtime.Trace`), so that a recording can run the module
  again on exactly what it received and compare its outputs
  (`ThinkingCap.Testing.Replay`, `mix tc.replay`). A module replays
  identically when its outputs depend only on what the framework gives
  it: its params and context, the tuples delivered, its releases, the
  commands applied, live param changes, and random numbers drawn from a
  seed among its params. It does not when it reads a clock, the
  blackboard (`rd`, `rdp`), files other than its RDF and WDF, or other
  processes itself. A module may implement `replay/0`, a keyword list:
  `trace: false` (a robot's driver: its inputs are its hardware, and
  `use ThinkingCap.Robot` says so) and `measurements: [{tag, path}]`,
  the parts of its outputs that measure the machine it ran on (a search's
  duration in microseconds): a replay compares the outputs without them,
  and counts them apart.

      @impl true
      def replay, do: [measurements: [{:plan, [:planning, :us]}]]
  """

  @type action ::
          {:out, tuple()}
          | {:out, {tuple(), keyword()}}
          | {:command, term()}
          | {:wire, iodata()}
          | {:attach_wire, Path.t(), iodata()}
          | {:detach_wire}
          | {:subscribe, tuple()}
          | {:set_param, atom(), term()}
  @type actions :: [action()]
  @type context :: %{
          name: atom(),
          robot: atom(),
          node: node(),
          activity: :periodic | :event | :background,
          rdf: Path.t() | nil,
          wdf: Path.t() | nil,
          handoff: term(),
          params: map()
        }
  @type release :: ThinkingCap.Cycle.release()

  @callback init(params :: keyword() | map(), context()) :: {:ok, term()} | {actions(), term()}
  @callback handle_cycle(release(), state :: term()) :: {actions(), term()}
  @callback handle_tuple(tuple(), state :: term()) :: {actions(), term()}
  @callback handle_background(state :: term()) :: {actions(), term()}
  @callback handle_info(term(), state :: term()) :: {actions(), term()}
  @callback handle_applied(ThinkingCap.Cycle.applied(), state :: term()) :: {actions(), term()}
  @callback handle_swap(old_module :: module(), old_state :: term(), context()) :: {:ok, term()}
  @callback terminate(reason :: term(), state :: term()) :: term()
  @callback handoff(state :: term()) :: term()
  @callback params() :: ThinkingCap.Config.Schema.fields()
  @callback handle_param(key :: atom(), value :: term(), state :: term()) ::
              {actions(), term()} | {:error, reason :: String.t(), term()}
  @callback replay() :: [trace: boolean(), measurements: [{atom(), [term()]}]]

  @optional_callbacks handle_swap: 3, handoff: 1, params: 0, handle_param: 3, replay: 0

  defmacro __using__(_opts) do
    quote do
      @behaviour ThinkingCap.Module

      @impl true
      def init(_params, _context), do: {:ok, nil}

      @impl true
      def handle_cycle(_release, state), do: {[], state}

      @impl true
      def handle_tuple(_tuple, state), do: {[], state}

      @impl true
      def handle_background(state) do
        # nothing to do: do not spin
        Process.sleep(100)
        {[], state}
      end

      @impl true
      def handle_info(_message, state), do: {[], state}

      @impl true
      def handle_applied(_applied, state), do: {[], state}

      @impl true
      def terminate(_reason, _state), do: :ok

      defoverridable init: 2,
                     handle_cycle: 2,
                     handle_tuple: 2,
                     handle_background: 1,
                     handle_info: 2,
                     handle_applied: 2,
                     terminate: 2
    end
  end
end
