defmodule ThinkingCap.Control.BlenderTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.{Blender, GoToPoint}
  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Testing.Lockstep

  @rdf """
  [
    name: "blender-test",
    footprint: [radius: 0.25],
    kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.2,
                 max_speed: 0.6, max_turn_rate: 1.8, max_acceleration: 1.0]
  ]
  """

  @release %{id: 0, cycle: 1, scheduled_ns: 0, released_ns: 0}
  @all [:avoid, :follow_wall, :cross_door, :go_to, :follow_path]

  defp context(rdf),
    do: %{name: :control, robot: :r1, node: node(), activity: :periodic, rdf: rdf, wdf: nil}

  defp start(params \\ []) do
    {actions, state} = Blender.init(params, context(nil))
    assert is_list(actions)
    state
  end

  defp feed(state, tuples) do
    Enum.reduce(tuples, state, fn tuple, state ->
      assert {[], state} = Blender.handle_tuple(tuple, state)
      state
    end)
  end

  # the drive command and the activations written by one cycle (which
  # remembers the command it gave, and nothing else)
  defp cycle(state) do
    {actions, after_cycle} = Blender.handle_cycle(@release, state)
    assert Map.delete(after_cycle, :last) == Map.delete(state, :last)

    case actions do
      [{:out, {{:drive, :r1, %{command: {:velocity, v, w}}}, _}} | _] ->
        assert after_cycle.last == {v * 1.0, w * 1.0}

      _ ->
        assert after_cycle.last == {0.0, 0.0}
    end

    assert [
             out: {{:drive, :r1, %{command: command}}, [key: {:drive, :r1}]},
             out: {{:activation, :r1, activations}, [key: {:activation, :r1}]}
           ] = actions

    {command, activations}
  end

  defp wall_ahead, do: LPS.from_points(for i <- 0..12, do: {0.4, -0.3 + i * 0.05})

  @pose {:pose, :r1, %{pose: {0.0, 0.0, 0.0}, covariance: nil}}

  describe "init" do
    @tag :tmp_dir
    test "subscribes to the robot's LPS, pose and plan; limits and radius from the RDF",
         %{tmp_dir: dir} do
      rdf = Path.join(dir, "robot.rdf")
      File.write!(rdf, @rdf)
      {actions, state} = Blender.init([], context(rdf))

      # the limits it drives within are set as its params, to be shown
      assert actions == [
               {:subscribe, {:lps, :r1, :_}},
               {:subscribe, {:pose, :r1, :_}},
               {:subscribe, {:plan, :r1, :_}},
               {:set_param, :max_speed, 0.6},
               {:set_param, :max_turn_rate, 1.8}
             ]

      assert state.limits == %{max_speed: 0.6, max_turn_rate: 1.8}
      assert state.radius == 0.25

      # the RDF's limits bound the command: a far goal ahead, nothing around
      state = feed(state, [{:lps, :r1, LPS.empty()}, @pose, {:plan, :r1, %{goal: {5.0, 0.0}}}])
      {{:velocity, v, w}, _} = cycle(state)
      assert v > 0.8 * 0.6 and v <= 0.6
      assert abs(w) < 1.0e-9
    end

    test "without an RDF, limits and radius from params; a bad RDF is refused" do
      state = start(max_speed: 0.3, max_turn_rate: 1.0, radius: 0.1)
      assert state.limits == %{max_speed: 0.3, max_turn_rate: 1.0}
      assert state.radius == 0.1

      assert_raise ArgumentError, ~r/:control: rdf:/, fn ->
        Blender.init([], context("/nonexistent/robot.rdf"))
      end
    end

    test "behaviours by name, name with params, module, or name, module, params, opts" do
      state =
        start(
          behaviours: [
            :avoid,
            {:go_to, [tolerance: 0.3]},
            {GoToPoint, []},
            {:slow_go_to, GoToPoint, [], weight: 0.5}
          ]
        )

      assert ThinkingCap.Control.Blend.names(state.blend) == [
               :avoid,
               :go_to,
               :go_to_point,
               :slow_go_to
             ]

      state = feed(state, [{:lps, :r1, LPS.empty()}, @pose, {:plan, :r1, %{goal: {0.25, 0.0}}}])
      # go_to's tolerance 0.3: reached; go_to_point's 0.1: not; slow_go_to weighted
      assert {_, %{go_to: +0.0, go_to_point: 1.0, slow_go_to: 0.5}} = cycle(state)

      assert_raise ArgumentError, ~r/neither a behaviour name/, fn ->
        start(behaviours: [{String, []}])
      end

      assert_raise ArgumentError, ~r/not a behaviour/, fn -> start(behaviours: ["avoid"]) end
    end
  end

  describe "cycle" do
    test "stops until it has an LPS, a pose and a plan" do
      state = start()
      assert {{:velocity, +0.0, +0.0}, activations} = cycle(state)
      assert activations == Map.new([:back_off | @all], &{&1, 0.0})

      plan = {:plan, :r1, %{goal: {3.0, 0.0}, path: nil, door: nil, state: :going}}
      assert {{:velocity, +0.0, +0.0}, _} = cycle(feed(state, [@pose, plan]))
      assert {{:velocity, +0.0, +0.0}, _} = cycle(feed(state, [{:lps, :r1, LPS.empty()}, plan]))
      assert {{:velocity, v, _}, _} = cycle(feed(state, [{:lps, :r1, LPS.empty()}, @pose, plan]))
      assert v > 0.2
    end

    test "stops while the plan is idle, done, blocked or waiting, or has neither goal nor path" do
      state = feed(start(), [{:lps, :r1, LPS.empty()}, @pose])

      for plan <- [
            %{goal: {3.0, 0.0}, state: :idle},
            %{goal: {3.0, 0.0}, path: [{0.0, 0.0}, {3.0, 0.0}], state: :done},
            %{goal: {3.0, 0.0}, path: nil, state: :blocked},
            %{goal: {3.0, 0.0}, state: :waiting},
            %{goal: nil, path: nil, door: nil, state: :going},
            %{path: [], state: :going},
            %{state: :going}
          ] do
        assert {{:velocity, +0.0, +0.0}, _} = cycle(feed(state, [{:plan, :r1, plan}]))
      end

      # stop states are a param
      state = %{start(stop_states: [:idle]) | lps: state.lps, pose: state.pose}

      assert {{:velocity, v, _}, _} =
               cycle(feed(state, [{:plan, :r1, %{goal: {3.0, 0.0}, state: :blocked}}]))

      assert v > 0.2
    end

    test "ignores other robots' tuples and malformed payloads" do
      state = start()

      assert feed(state, [
               {:lps, :r2, LPS.empty()},
               {:pose, :r2, %{pose: {1.0, 1.0, 1.0}}},
               {:plan, :r2, %{goal: {1.0, 1.0}}},
               {:pose, :r1, %{position: {1.0, 1.0}}},
               {:scan, :r1, %{}}
             ]) == state
    end

    test "an obstacle between the robot and its goal: turns and slows, activations published" do
      state =
        feed(start(max_speed: 0.5, max_turn_rate: 2.0), [
          {:lps, :r1, wall_ahead()},
          @pose,
          {:plan, :r1, %{goal: {3.0, 0.0}, path: nil, door: nil, state: :going}}
        ])

      {{:velocity, v, w}, activations} = cycle(state)
      assert Map.keys(activations) |> Enum.sort() == Enum.sort([:back_off | @all])
      assert activations.avoid > 0.8
      assert activations.go_to < 0.2
      assert activations.follow_path == 0.0
      assert w > 0.3 * 2.0
      # the arc it starts on turns away within the 0.3 m of clearance ahead
      assert v < 0.5 * 0.5
      assert v / w < 0.3

      # without the default precedence, go-to stays fully active
      state = %{start(unless: %{go_to: []}) | lps: state.lps, pose: state.pose, plan: state.plan}
      assert {_, %{go_to: 1.0}} = cycle(state)
    end

    test "with a path, follows it (go-to gives way); the plan may weigh behaviours" do
      plan = %{goal: {2.0, 2.0}, path: [{0.0, 0.0}, {2.0, 0.0}, {2.0, 2.0}], state: :going}
      state = feed(start(), [{:lps, :r1, LPS.empty()}, @pose, {:plan, :r1, plan}])

      {{:velocity, v, w}, activations} = cycle(state)
      assert activations.follow_path == 1.0
      assert activations.go_to == 0.0
      # along the path's first leg, not towards the goal (up and to the left)
      assert abs(w) < 1.0e-9
      assert v > 0.3

      plan = Map.put(plan, :weights, %{follow_path: 0.0})
      {{:velocity, _, w}, activations} = cycle(feed(state, [{:plan, :r1, plan}]))
      assert activations.follow_path == 0.0
      assert activations.go_to == 1.0
      assert w > 0.3
    end

    test "follows the latest pose" do
      plan = {:plan, :r1, %{goal: {0.0, 3.0}, state: :going}}
      state = feed(start(), [{:lps, :r1, LPS.empty()}, @pose, plan])
      {{:velocity, _, w_left}, _} = cycle(state)

      {{:velocity, _, w_ahead}, _} =
        cycle(feed(state, [{:pose, :r1, %{pose: {0.0, 0.0, :math.pi() / 2}}}]))

      assert w_left > 0.5
      assert abs(w_ahead) < 1.0e-9
    end
  end

  describe "bumper reflex" do
    # a cycle at time `t` (s): the command, the activations and the state
    defp cycle_at(state, t) do
      release = %{@release | scheduled_ns: round(t * 1.0e9)}

      {[out: {{:drive, :r1, %{command: command}}, _}, out: {{:activation, :r1, act}, _}], state} =
        Blender.handle_cycle(release, state)

      {command, act, state}
    end

    # driving to a goal ahead, an obstacle touching the robot's front left
    defp pressed_left(params \\ []) do
      touching = LPS.from_points([{0.12, 0.16}])
      plan = {:plan, :r1, %{goal: {3.0, -1.0}, state: :going}}
      state = feed(start([bumpers: [:bumper]] ++ params), [{:lps, :r1, touching}, @pose, plan])
      assert {{:velocity, v, _}, %{back_off: +0.0}, state} = cycle_at(state, 0.0)
      assert v > 0.0
      state
    end

    @tag :tmp_dir
    test "the RDF's bumpers are subscribed to, or the bumpers param's",
         %{tmp_dir: dir} do
      rdf = Path.join(dir, "robot.rdf")

      File.write!(
        rdf,
        String.replace(
          @rdf,
          "kinematics:",
          "sensors: [[name: :front, type: :bumper]], kinematics:"
        )
      )

      {actions, state} = Blender.init([], context(rdf))
      assert {:subscribe, {:front, :r1, :_}} in actions
      assert state.reflex.bumpers == [:front]

      {actions, _} = Blender.init([bumpers: [:left_bumper]], context(rdf))
      assert {:subscribe, {:left_bumper, :r1, :_}} in actions
      refute {:subscribe, {:front, :r1, :_}} in actions

      {actions, _} = Blender.init([], context(nil))
      refute Enum.any?(actions, &match?({:subscribe, {:bumper, _, _}}, &1))
    end

    test "a press while driving: backs off straight, turns away from the contact, then drives" do
      state = pressed_left() |> feed([{:bumper, :r1, %{pressed: true, stamp: 0.0}}])

      assert {{:velocity, -0.1, +0.0}, activations, state} = cycle_at(state, 0.1)
      assert activations.back_off == 1.0
      assert Enum.all?(@all, &(activations[&1] == 0.0))

      # the bumper released: the back-off runs its time (1 s), then the
      # turn on the spot: the contact on the left, clockwise, at half the
      # top turn rate (1.5 rad/s without an RDF) for 0.5 rad
      state = feed(state, [{:bumper, :r1, %{pressed: false, stamp: 0.1}}])
      assert {{:velocity, -0.1, +0.0}, %{back_off: 1.0}, state} = cycle_at(state, 1.0)
      assert {{:velocity, +0.0, -0.75}, %{back_off: 1.0}, state} = cycle_at(state, 1.1)
      assert {{:velocity, +0.0, -0.75}, %{back_off: 1.0}, state} = cycle_at(state, 1.7)
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(state, 1.8)
      assert v > 0.0
    end

    test "the reading's side wins over the LPS's; the back-off's time, speed, angle are params" do
      state =
        pressed_left(back_off_time: 0.5, back_off_speed: 0.05, back_off_angle: 0.15)
        |> feed([{:bumper, :r1, %{pressed: true, left: false, right: true}}])

      assert {{:velocity, -0.05, +0.0}, _, state} = cycle_at(state, 0.1)
      assert {{:velocity, +0.0, 0.75}, _, state} = cycle_at(state, 0.6)
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(state, 0.8)
      assert v > 0.0
    end

    test "a press on no known side: backs off, no turn" do
      plan = {:plan, :r1, %{goal: {3.0, 0.0}, state: :going}}
      state = feed(start(bumpers: [:bumper]), [{:lps, :r1, LPS.empty()}, @pose, plan])
      state = %{state | last: {0.3, 0.0}} |> feed([{:bumper, :r1, %{pressed: true}}])
      assert {{:velocity, -0.1, +0.0}, _, state} = cycle_at(state, 0.0)
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(state, 1.0)
      assert v > 0.0
    end

    test "a press during the back-off (something behind) ends it" do
      state = pressed_left() |> feed([{:bumper, :r1, %{pressed: true}}])
      assert {{:velocity, -0.1, _}, _, state} = cycle_at(state, 0.1)
      state = feed(state, [{:bumper, :r1, %{pressed: true}}])
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(state, 0.2)
      assert v >= 0.0
    end

    test "no back-off for a press while standing still, or while the plan stops the robot" do
      state = pressed_left()
      still = %{state | last: {0.0, 0.0}} |> feed([{:bumper, :r1, %{pressed: true}}])
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(still, 0.1)
      assert v > 0.0

      done = feed(state, [{:plan, :r1, %{state: :done}}, {:bumper, :r1, %{pressed: true}}])
      assert {{:velocity, +0.0, +0.0}, %{back_off: +0.0}, done} = cycle_at(done, 0.1)
      # the press is forgotten, not acted on when the plan resumes
      resumed = feed(done, [{:plan, :r1, %{goal: {3.0, -1.0}, state: :going}}])

      assert {{:velocity, v, _}, %{back_off: +0.0}, _} =
               cycle_at(%{resumed | last: state.last}, 0.2)

      assert v > 0.0
    end

    test "a rise of the plan's recoveries backs the robot off, bumper or not" do
      # no bumper; driving to a goal ahead, something touching its front left
      touching = LPS.from_points([{0.12, 0.16}])
      plan = %{goal: {3.0, -1.0}, state: :moving, recoveries: 2}
      state = feed(start(), [{:lps, :r1, touching}, @pose, {:plan, :r1, plan}])

      # the first count seen asks for nothing (it may be old), the same
      # count again neither
      assert {{:velocity, v, _}, %{back_off: +0.0}, state} = cycle_at(state, 0.0)
      assert v > 0.0
      state = feed(state, [{:plan, :r1, plan}])
      assert {{:velocity, v, _}, %{back_off: +0.0}, state} = cycle_at(state, 0.1)
      assert v > 0.0

      # stuck: the count rises; standing still does not matter
      state = %{state | last: {0.0, 0.0}} |> feed([{:plan, :r1, %{plan | recoveries: 3}}])
      assert {{:velocity, -0.1, +0.0}, %{back_off: 1.0}, state} = cycle_at(state, 0.2)
      # the turn away from the LPS's nearer side (left): clockwise
      assert {{:velocity, +0.0, w}, %{back_off: 1.0}, state} = cycle_at(state, 1.2)
      assert w < 0.0
      assert {{:velocity, v, _}, %{back_off: +0.0}, _} = cycle_at(state, 2.0)
      assert v > 0.0
    end

    @tag :tmp_dir
    test "a car-like robot backs off along an arc its steering allows", %{tmp_dir: dir} do
      rdf = Path.join(dir, "car.rdf")

      File.write!(rdf, """
      [
        name: "car",
        footprint: [radius: 0.25],
        sensors: [[name: :bumper, type: :bumper]],
        kinematics: [type: :ackermann, wheelbase: 0.5, track: 0.3, max_steering: 0.5,
                     max_speed: 1.0, max_turn_rate: 2.0]
      ]
      """)

      {_, state} = Blender.init([back_off_speed: 0.2], context(rdf))
      touching = LPS.from_points([{0.2, 0.2}])
      plan = {:plan, :r1, %{goal: {3.0, 0.0}, state: :going}}
      state = feed(state, [{:lps, :r1, touching}, @pose, plan])
      state = %{state | last: {0.3, 0.0}} |> feed([{:bumper, :r1, %{pressed: true}}])

      # along the tightest arc, tan(0.5) / 0.5 = 1.09 per metre at 0.2
      # m/s, the front swinging away from the contact on the left; no
      # turn on the spot after it
      assert {{:velocity, -0.2, w}, %{back_off: 1.0}, state} = cycle_at(state, 0.1)
      assert_in_delta w, -0.2 * :math.tan(0.5) / 0.5, 1.0e-9
      assert {{:velocity, -0.2, ^w}, %{back_off: 1.0}, state} = cycle_at(state, 1.0)
      assert {_, %{back_off: +0.0}, _} = cycle_at(state, 1.1)
    end
  end

  test "runs as a periodic module: subscriptions honoured, drive written each period" do
    lock =
      Lockstep.new(robot: :r1, modules: [control: {Blender, [], period: 0.1}])
      |> Lockstep.deliver({:lps, :r1, LPS.empty()})
      |> Lockstep.deliver(@pose)
      |> Lockstep.deliver({:plan, :r1, %{goal: {2.0, 0.0}, state: :going}})
      |> Lockstep.advance(0.1)

    assert {:drive, :r1, %{command: {:velocity, v, w}}} = Lockstep.latest(lock, {:drive, :r1, :_})
    assert v > 0.2 and abs(w) < 1.0e-9
    assert {:activation, :r1, %{go_to: 1.0}} = Lockstep.latest(lock, {:activation, :r1, :_})

    lock = lock |> Lockstep.deliver({:plan, :r1, %{state: :done}}) |> Lockstep.advance(0.2)

    assert {:drive, :r1, %{command: {:velocity, +0.0, +0.0}}} =
             Lockstep.latest(lock, {:drive, :r1, :_})
  end

  describe "live parameters" do
    @tag :tmp_dir
    test "max_speed set while it runs bounds the next cycle; above the RDF's it is refused",
         %{tmp_dir: dir} do
      rdf = Path.join(dir, "robot.rdf")
      File.write!(rdf, @rdf)

      lock =
        Lockstep.new(robot: :r1, rdf: rdf, modules: [control: {Blender, [], period: 0.1}])
        |> Lockstep.deliver({:lps, :r1, LPS.empty()})
        |> Lockstep.deliver(@pose)
        |> Lockstep.deliver({:plan, :r1, %{goal: {5.0, 0.0}, state: :going}})

      # the RDF's limits, shown as its params
      assert %{max_speed: 0.6, max_turn_rate: 1.8, radius: 0.2} = Lockstep.params(lock, :control)
      lock = Lockstep.advance(lock, 0.0)

      assert {:drive, :r1, %{command: {:velocity, v, _}}} =
               Lockstep.latest(lock, {:drive, :r1, :_})

      assert v > 0.8 * 0.6

      assert {:ok, lock} = Lockstep.set_param(lock, :control, :max_speed, 0.2)
      lock = Lockstep.advance(lock, 0.1)

      assert {:drive, :r1, %{command: {:velocity, v, _}}} =
               Lockstep.latest(lock, {:drive, :r1, :_})

      assert v > 0.8 * 0.2 and v <= 0.2

      assert {:param, :r1, %{module: :control, key: :max_speed, value: 0.2}} =
               Lockstep.latest(lock, {:param, :r1, :_})

      assert {:error,
              "ThinkingCap.Control.Blender refused max_speed: 0.9 is above the robot's max_speed of 0.6 (its RDF)"} =
               Lockstep.set_param(lock, :control, :max_speed, 0.9)

      assert {:error, "max_speed: expected a number from 0.0 to 10.0, got -1"} =
               Lockstep.set_param(lock, :control, :max_speed, -1)

      assert {:error, message} = Lockstep.set_param(lock, :control, :behaviours, [:avoid])
      assert message =~ "read-only"
      assert Lockstep.params(lock, :control).max_speed == 0.2
    end
  end

  describe "a car-like robot" do
    @tricycle """
    [
      name: "blender-tricycle",
      footprint: [radius: 0.25],
      kinematics: [type: :tricycle, wheelbase: 0.5, max_steering: 0.8,
                   max_speed: 0.6, max_turn_rate: 1.8, max_acceleration: 1.0]
    ]
    """

    # the regression of the freeze: a goal behind made the blend ask for
    # {0, w}, which a car's steering limit cuts to {0, 0}
    @tag :tmp_dir
    test "with the goal behind it, creeps along its tightest arc instead of standing still",
         %{tmp_dir: dir} do
      rdf = Path.join(dir, "tricycle.rdf")
      File.write!(rdf, @tricycle)
      {_, state} = Blender.init([], context(rdf))
      k = :math.tan(0.8) / 0.5
      plan = {:plan, :r1, %{goal: {-3.0, 0.5}, state: :moving}}

      {{:velocity, v, w}, _} = cycle(feed(state, [{:lps, :r1, LPS.empty()}, @pose, plan]))
      assert v > 0.05
      assert w > 0 and abs(w) <= v * k + 1.0e-9

      # a wall ahead: it backs up, turning the same way round
      {{:velocity, v, w}, _} = cycle(feed(state, [{:lps, :r1, wall_ahead()}, @pose, plan]))
      assert v < -0.05
      assert w > 0 and abs(w) <= abs(v) * k + 1.0e-9

      # hemmed in front and back: it stops
      boxed =
        LPS.from_points(for i <- 0..12, y <- [-0.3 + i * 0.05], x <- [0.4, -0.4], do: {x, y})

      assert {{:velocity, +0.0, +0.0}, _} = cycle(feed(state, [{:lps, :r1, boxed}, @pose, plan]))

      # a differential robot in the same place turns on the spot
      {{:velocity, v, w}, _} = cycle(feed(start(), [{:lps, :r1, LPS.empty()}, @pose, plan]))

      assert abs(v) < 0.05 and w > 0.5
    end
  end
end
