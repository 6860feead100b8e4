defmodule ThinkingCap.Control.Blender do
  @moduledoc """
  The control cycle as a `ThinkingCap.Module`: blends the fuzzy behaviours
  (`ThinkingCap.Control.Blend`) on the latest Local Perceptual Space, pose
  and plan, and writes the robot's drive command. Periodic: the ADF gives
  the period (e.g. 0.1 s).

      control: [
        module: ThinkingCap.Control.Blender,
        activity: :periodic, period: 0.1, deadline: 0.02,
        params: [behaviours: [:avoid, :follow_wall, :cross_door, :go_to, :follow_path]]
      ]

  ## Blackboard

  Reads (subscribed in `init/2`, the latest of each kept):

    * `{:lps, robot, %ThinkingCap.Perception.LPS{}}`;
    * `{:pose, robot, %{pose: {x, y, θ}}}` - the estimated world pose;
    * `{:plan, robot, %{goal: {x, y} | nil, path: [{x, y}] | nil,
      door: %{centre: {x, y}, heading: θ, width: m} | nil, state: atom}}`
      - absent fields mean none; an optional `weights: %{behaviour => degree}`
      weighs behaviours (`ThinkingCap.Control.Blend`).

  Writes, every cycle:

    * `{:drive, robot, %{command: {:velocity, v, w}}}` (key `{:drive, robot}`);
    * `{:activation, robot, %{behaviour => degree}}` (key `{:activation, robot}`),
      with `back_off` (see "Bumper reflex").

  ## Bumper reflex

  When a bumper closes while the robot drives forwards or turns, the
  robot backs off straight for `back_off_time` at `back_off_speed`,
  turns on the spot by `back_off_angle` away from the contact (a car-like
  robot backs along an arc instead), and then the blend drives again
  (`ThinkingCap.Control.BackOff`). The bumpers are the RDF's sensors of
  type `:bumper` (or the `bumpers` param); their readings,
  `{name, robot, %{pressed: boolean}}`, are subscribed to. The plan may
  ask for the same back-off: when its `recoveries` count rises
  (`ThinkingCap.Planner.Monitor`, a robot making no progress), the
  robot backs off whatever it is doing, bumper or not. The activations
  carry `back_off` (1.0 while backing off, else 0.0; the behaviours' are
  then 0.0).

  A car-like robot (tricycle, Ackermann in the RDF) cannot turn on the
  spot: a blended twist sharper than its steering allows is made one it
  can drive (`ThinkingCap.Control.Steering.feasible/4`: creep along the
  tightest arc, forwards or in reverse, where the LPS is clear).

  It stops (`{:velocity, 0.0, 0.0}`, every activation 0) until it has an
  LPS, a pose and a plan, and while the plan's state is one of
  `stop_states` or the plan has neither a goal nor a path.

  ## Params

    * `behaviours` - default `#{inspect([:avoid, :follow_wall, :cross_door, :go_to, :follow_path])}`;
      each one of
      * a name: `:avoid` (`ThinkingCap.Control.AvoidObstacles`),
        `:follow_wall` (`ThinkingCap.Control.FollowWall`), `:cross_door`
        (`ThinkingCap.Control.CrossDoor`), `:go_to`
        (`ThinkingCap.Control.GoToPoint`), `:follow_path`
        (`ThinkingCap.Control.FollowPath`);
      * `{name, params}` - a name with the behaviour's params;
      * `{module, params}` - any `ThinkingCap.Control.Behaviour`, named
        after the module (`MyApp.Dock` → `:dock`);
      * `{name, module, params}` or `{name, module, params, opts}` (opts
        as in `ThinkingCap.Control.Blend`: `weight:`, `unless:`);
    * `unless` - precedence, `%{name => [names]}`, replacing the default
      for the names given. Default: `go_to` unless `avoid`, `cross_door`,
      `follow_path` (with a path, follow it); `follow_path` unless `avoid`,
      `cross_door`; `follow_wall` unless `avoid`, `cross_door`,
      `follow_path` (a planned path already keeps off the walls); names
      absent from
      `behaviours` are dropped;
    * `stop_states` - plan states in which the robot stands still, default
      `[:idle, :done, :failed, :blocked, :unreachable, :waiting]`
      (`ThinkingCap.Planner.Monitor`: no task, task done, task failed,
      waiting to retry a blocked route or a goal no path leads to, no pose
      or map yet);
    * `max_speed`, `max_turn_rate` - the top speed (m/s) and turn rate
      (rad/s) the blend commands: with an RDF (`context.rdf`), at most its
      kinematics' limits, which they default to; without one, defaults 0.5
      m/s and 1.5 rad/s;
    * `radius` (0.2 m) - used only without an RDF: with one, the radius
      comes from its footprint;
    * `bumpers` - the sensors whose presses start a back-off; default the
      RDF's sensors of type `:bumper`, none without an RDF;
    * `back_off_time` (1.0 s), `back_off_speed` (0.1 m/s, at most
      `max_speed`), `back_off_angle` (0.5 rad) - the back-off (see
      "Bumper reflex").

  `max_speed` and `max_turn_rate` are **live parameters**
  (`ThinkingCap.Module`): set while the robot runs
  (`ThinkingCap.Runtime.set_param(:control, :max_speed, 0.2)`, the
  dashboard's Params panel), the next cycle blends within the new limit;
  a value above the RDF's limit is refused, naming it. The others are
  read-only (read at start). At start the module sets the limits it
  drives within as its params (`{:set_param, ...}`), so they are shown
  and recorded even when the RDF gave them.
  """
  use ThinkingCap.Module

  alias ThinkingCap.Control.{BackOff, Blend, Steering}

  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Robot.{Description, Kinematics}
  alias ThinkingCap.Tuples
  require Tuples

  @named ThinkingCap.Control.behaviours()

  @default_behaviours [:avoid, :follow_wall, :cross_door, :go_to, :follow_path]

  @default_unless %{
    go_to: [:avoid, :cross_door, :follow_path],
    follow_path: [:avoid, :cross_door],
    follow_wall: [:avoid, :cross_door, :follow_path]
  }

  @stop {:velocity, 0.0, 0.0}
  # the back-off's defaults
  @back_off %BackOff{}
  @stop_states [:idle, :done, :failed, :blocked, :unreachable, :waiting]

  @params [
    behaviours:
      {{:list, :any},
       default: @default_behaviours, read_only: true, doc: "the behaviours blended (see above)"},
    unless:
      {:any, default: nil, read_only: true, doc: "precedence, %{name => [names]} (see above)"},
    stop_states:
      {{:list, :atom},
       default: @stop_states, read_only: true, doc: "plan states in which the robot stands still"},
    max_speed:
      {{:number_range, 0.0, 10.0},
       default: nil, doc: "m/s, the top speed (at most the RDF's, its default; else 0.5)"},
    max_turn_rate:
      {{:number_range, 0.0, 20.0},
       default: nil, doc: "rad/s, the top turn rate (at most the RDF's, its default; else 1.5)"},
    radius:
      {:pos_number, default: 0.2, read_only: true, doc: "m, the robot's radius without an RDF"},
    bumpers:
      {{:list, :atom},
       default: nil,
       read_only: true,
       doc: "sensors whose presses start a back-off (RDF's bumpers)"},
    back_off_time:
      {{:number_range, 0.0, 10.0},
       default: @back_off.time, read_only: true, doc: "s, a back-off's length"},
    back_off_speed:
      {{:number_range, 0.0, 10.0},
       default: @back_off.speed,
       read_only: true,
       doc: "m/s, a back-off's speed (at most max_speed)"},
    back_off_angle:
      {{:number_range, 0.0, 3.15},
       default: @back_off.angle,
       read_only: true,
       doc: "rad, the turn away from the contact after backing off"}
  ]

  @doc "The params this module takes (`c:ThinkingCap.Module.params/0`)."
  @impl true
  @spec params() :: keyword()
  def params, do: @params

  @impl true
  def init(params, context) do
    params = if is_map(params), do: Map.to_list(params), else: params || []
    robot = context.robot
    {ceiling, radius, curvature, rdf_bumpers} = robot_limits(params, context)

    # the params bound the RDF's limits, never raise them
    limits =
      Map.new(ceiling, fn {key, max} ->
        {key, min(number(Keyword.get(params, key)) || max, max)}
      end)

    unless_map = Map.merge(@default_unless, Map.new(Keyword.get(params, :unless, %{})))
    specs = params |> Keyword.get(:behaviours, @default_behaviours) |> Enum.map(&spec/1)
    names = Enum.map(specs, &elem(&1, 0))

    specs =
      Enum.map(specs, fn {name, module, bparams, opts} ->
        default = for other <- Map.get(unless_map, name, []), other in names, do: other
        {name, module, bparams, Keyword.put_new(opts, :unless, default)}
      end)

    state = %{
      robot: robot,
      blend: Blend.init(behaviours: specs),
      limits: limits,
      ceiling: if(is_binary(context[:rdf]), do: ceiling),
      radius: radius,
      curvature: curvature,
      reflex: reflex(params, rdf_bumpers, limits),
      stop_states: Keyword.get(params, :stop_states, @stop_states),
      lps: nil,
      pose: nil,
      plan: nil,
      last: {0.0, 0.0}
    }

    subscribe =
      [
        subscribe: Tuples.lps(robot),
        subscribe: Tuples.pose(robot),
        subscribe: Tuples.plan(robot)
      ] ++ for(bumper <- state.reflex.bumpers, do: {:subscribe, Tuples.reading(bumper, robot)})

    # the limits it drives within, as its params: shown and recorded
    shown = for {key, value} <- limits, do: {:set_param, key, value}
    {subscribe ++ Enum.sort(shown), state}
  end

  defp number(x) when is_number(x), do: x * 1.0
  defp number(_), do: nil

  # the params' back-off, BackOff's defaults for those not given
  defp reflex(params, rdf_bumpers, limits) do
    BackOff.new(Keyword.get(params, :bumpers) || rdf_bumpers,
      time: Keyword.get(params, :back_off_time),
      speed: Keyword.get(params, :back_off_speed),
      angle: Keyword.get(params, :back_off_angle),
      max_speed: limits.max_speed
    )
  end

  @doc """
  A live change of `max_speed` or `max_turn_rate` (the others are
  read-only): the next cycle blends within it. Above the RDF's limit it
  is refused.
  """
  @impl true
  def handle_param(key, value, state) when key in [:max_speed, :max_turn_rate] do
    case state.ceiling do
      %{^key => max} when value > max ->
        {:error, "#{value} is above the robot's #{key} of #{max} (its RDF)", state}

      _ ->
        {[], %{state | limits: Map.put(state.limits, key, value)}}
    end
  end

  defp robot_limits(_params, %{rdf: rdf} = context) when is_binary(rdf) do
    case Description.load(rdf) do
      {:ok, description} ->
        limits = Kinematics.limits(description.kinematics)

        bumpers = for %{type: :bumper, name: name} <- description.sensors, do: name

        {%{max_speed: limits.max_speed * 1.0, max_turn_rate: limits.max_turn_rate * 1.0},
         description.footprint.radius * 1.0, Steering.max_curvature(description.kinematics),
         bumpers}

      {:error, message} ->
        raise ArgumentError, "#{inspect(context[:name])}: rdf: #{message}"
    end
  end

  defp robot_limits(params, _context) do
    {%{
       max_speed: number(Keyword.get(params, :max_speed)) || 0.5,
       max_turn_rate: number(Keyword.get(params, :max_turn_rate)) || 1.5
     }, (number(Keyword.get(params, :radius)) || 0.2) * 1.0, :infinity, []}
  end

  defp spec(name) when is_map_key(@named, name), do: {name, @named[name], [], []}

  defp spec({name, params}) when is_map_key(@named, name) and is_list(params),
    do: {name, @named[name], params, []}

  defp spec({module, params}) when is_atom(module) and is_list(params) do
    unless Code.ensure_loaded?(module) and function_exported?(module, :evaluate, 2) do
      raise ArgumentError,
            "Blender: #{inspect(module)} is neither a behaviour name " <>
              "(#{inspect(Map.keys(@named))}) nor a ThinkingCap.Control.Behaviour module"
    end

    name = module |> Module.split() |> List.last() |> Macro.underscore() |> String.to_atom()
    {name, module, params, []}
  end

  defp spec({name, module, params}), do: {name, module, params, []}
  defp spec({_name, _module, _params, _opts} = spec), do: spec

  defp spec(other),
    do: raise(ArgumentError, "Blender: not a behaviour: #{inspect(other)}")

  @impl true
  def handle_tuple(Tuples.lps(robot, %LPS{} = lps), %{robot: robot} = state),
    do: {[], %{state | lps: lps}}

  def handle_tuple(Tuples.pose(robot, %{pose: {_, _, _} = pose}), %{robot: robot} = state),
    do: {[], %{state | pose: pose}}

  def handle_tuple(Tuples.plan(robot, plan), %{robot: robot} = state) when is_map(plan) do
    reflex =
      case plan do
        %{recoveries: n} when is_integer(n) and n >= 0 -> BackOff.recoveries(state.reflex, n)
        _ -> state.reflex
      end

    {[], %{state | plan: plan, reflex: reflex}}
  end

  def handle_tuple(Tuples.reading(sensor, robot, %{} = payload), %{robot: robot} = state)
      when is_atom(sensor) do
    if BackOff.bumper?(state.reflex, sensor),
      do: {[], %{state | reflex: BackOff.reading(state.reflex, payload)}},
      else: {[], state}
  end

  def handle_tuple(_tuple, state), do: {[], state}

  @impl true
  def handle_cycle(release, state) do
    {command, activations, reflex} =
      case inputs(state) do
        nil ->
          {@stop, idle(state, 0.0), BackOff.reset(state.reflex)}

        inputs ->
          inputs = Map.merge(inputs, %{last: state.last, curvature: state.curvature})

          case BackOff.command(state.reflex, release.scheduled_ns / 1.0e9, inputs) do
            {nil, reflex} ->
              {command, activations} = blend(state, inputs)
              {command, Map.put(activations, :back_off, 0.0), reflex}

            {{v, w}, reflex} ->
              {{:velocity, v, w}, idle(state, 1.0), reflex}
          end
      end

    state = %{state | last: last(command), reflex: reflex}

    robot = state.robot

    actions = [
      out: Tuples.keyed(Tuples.drive(robot, %{command: command})),
      out: Tuples.keyed(Tuples.activation(robot, activations))
    ]

    {actions, state}
  end

  defp blend(state, inputs) do
    %{command: {v, w}, activations: activations} = Blend.run(state.blend, inputs)
    {v, w} = Steering.feasible({v, w}, state.curvature, state.lps, radius: state.radius)
    {{:velocity, v, w}, activations}
  end

  # every behaviour at 0 (standing still, or the reflex driving)
  defp idle(state, back_off),
    do: state.blend |> Blend.names() |> Map.new(&{&1, 0.0}) |> Map.put(:back_off, back_off)

  defp last({:velocity, v, w}), do: {v * 1.0, w * 1.0}
  defp last(_stop), do: {0.0, 0.0}

  @doc """
  The behaviours' inputs from the latest LPS, pose and plan, or `nil` when
  the robot should stop (see the moduledoc).
  """
  @spec inputs(map()) :: ThinkingCap.Control.Behaviour.inputs() | nil
  def inputs(%{lps: %LPS{} = lps, pose: {_, _, _} = pose, plan: %{} = plan} = state) do
    goal = Map.get(plan, :goal)
    path = Map.get(plan, :path)
    path = if path == [], do: nil, else: path

    if Map.get(plan, :state) in state.stop_states or (goal == nil and path == nil) do
      nil
    else
      %{
        lps: lps,
        pose: pose,
        goal: goal,
        path: path,
        door: Map.get(plan, :door),
        limits: state.limits,
        radius: state.radius,
        weights: Map.get(plan, :weights) || %{}
      }
    end
  end

  def inputs(_state), do: nil
end
