defmodule ThinkingCap.Control.BlendTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.{
    AvoidObstacles,
    Behaviour,
    Blend,
    CrossDoor,
    Fuzzy,
    Geometry,
    GoToPoint
  }

  alias ThinkingCap.Perception.LPS

  @limits %{max_speed: 0.5, max_turn_rate: 2.0}
  @radius 0.2
  @dt 0.1

  # a behaviour with a fixed context and fixed sets, for the arithmetic of blending
  defmodule Fixed do
    @moduledoc false
    use ThinkingCap.Control.Behaviour

    @impl true
    def init(params), do: Map.new(params)

    @impl true
    def context(_inputs, p), do: p.context

    @impl true
    def outputs(inputs, p) do
      Behaviour.control([[if: true, then: [v: p.v, w: p.w]]], %{}, [], inputs)
    end
  end

  defp inputs(world_points, pose, overrides \\ []) do
    local = Enum.map(world_points, &Geometry.to_robot(pose, &1))

    Map.merge(
      %{
        lps: LPS.from_points(local),
        pose: pose,
        goal: nil,
        path: nil,
        door: nil,
        limits: @limits,
        radius: @radius
      },
      Map.new(overrides)
    )
  end

  defp line({x0, y0}, {x1, y1}, step) do
    n = max(1, round(:math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2) / step))
    for i <- 0..n, do: {x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n}
  end

  # A point robot driven by `control` (inputs -> {v, w}) among static
  # obstacle points, its LPS rebuilt from them every step: {:reached,
  # steps, closest} | {:collision, steps, closest} | {:timeout, steps, closest}
  defp drive(control, points, start, base, steps \\ 400) do
    {gx, gy} = base.goal

    Enum.reduce_while(1..steps, {start, :infinity}, fn k, {pose, closest} ->
      {v, w} = control.(inputs(points, pose, base))
      {x, y, _} = pose = ThinkingCap.Robot.Kinematics.integrate(pose, {v, w}, @dt)

      d =
        points
        |> Enum.map(fn {px, py} -> :math.sqrt((px - x) ** 2 + (py - y) ** 2) end)
        |> Enum.min()

      closest = min(closest, d)

      cond do
        d < @radius -> {:halt, {:collision, k, closest}}
        :math.sqrt((gx - x) ** 2 + (gy - y) ** 2) < 0.15 -> {:halt, {:reached, k, closest}}
        k == steps -> {:halt, {:timeout, k, closest}}
        true -> {:cont, {pose, closest}}
      end
    end)
  end

  defp blended(blend), do: fn inputs -> Blend.run(blend, inputs).command end

  # what a controller without fuzzy blending would do: defuzzify each
  # behaviour alone and average the crisp commands weighted by context
  defp naive_average(behaviours) do
    fn inputs ->
      parts =
        for {module, params} <- behaviours do
          {c, out} = Behaviour.evaluate({module, module.init(params)}, inputs)
          {c, Fuzzy.defuzzify(out.v, 0.0), Fuzzy.defuzzify(out.w, 0.0)}
        end

      total = parts |> Enum.map(&elem(&1, 0)) |> Enum.sum()

      if total == 0.0 do
        {0.0, 0.0}
      else
        {Enum.sum(for {c, v, _} <- parts, do: c * v) / total,
         Enum.sum(for {c, _, w} <- parts, do: c * w) / total}
      end
    end
  end

  @go_to_unless_avoid [
    {:avoid, AvoidObstacles, []},
    {:go_to, GoToPoint, [], unless: [:avoid]}
  ]

  describe "activation and weighting" do
    test "a single behaviour: its context is its activation, its set is clipped at it" do
      blend = Blend.init(behaviours: [{:a, Fixed, [context: 0.4, v: :fast, w: :left]}])

      %{command: {v, w}, activations: %{a: a}, outputs: outputs} =
        Blend.run(blend, inputs([], {0.0, 0.0, 0.0}))

      assert a == 0.4
      assert_in_delta Fuzzy.height(outputs.v), 0.4, 1.0e-12
      # clipping a symmetric triangle keeps its centroid
      assert_in_delta w, 0.4 * 2.0, 1.0e-9
      assert v > 0.7 * 0.5
    end

    test "one set, defuzzified once: an active behaviour outweighs a faint one" do
      blend =
        Blend.init(
          behaviours: [
            {:strong, Fixed, [context: 1.0, v: :slow, w: :hard_left]},
            {:faint, Fixed, [context: 0.1, v: :slow, w: :hard_right]}
          ]
        )

      %{command: {_, w}} = Blend.run(blend, inputs([], {0.0, 0.0, 0.0}))
      assert w > 0.6 * 2.0
    end

    test "fixed weights, plan weights and unless: combine by minimum" do
      blend =
        Blend.init(
          behaviours: [
            {:a, Fixed, [context: 0.9, v: :slow, w: :left], weight: 0.7},
            {:b, Fixed, [context: 1.0, v: :fast, w: :right], unless: [:a]},
            {:c, Fixed, [context: 0.8, v: :medium, w: :straight]}
          ]
        )

      scene = inputs([], {0.0, 0.0, 0.0})
      assert %{a: 0.7, b: b, c: 0.8} = Blend.run(blend, scene).activations
      assert_in_delta b, 0.3, 1.0e-12

      # the plan weighs a down: it inhibits b less
      %{activations: acts} = Blend.run(blend, Map.put(scene, :weights, %{a: 0.2, c: 0.5}))
      assert acts.a == 0.2
      assert_in_delta acts.b, 0.8, 1.0e-12
      assert acts.c == 0.5
    end

    test "no active behaviour: no opinion, stop" do
      blend = Blend.init(behaviours: [{:a, Fixed, [context: 0.0, v: :fast, w: :left]}])

      assert %{command: {+0.0, +0.0}, activations: %{a: +0.0}} =
               Blend.run(blend, inputs([], {0.0, 0.0, 0.0}))

      assert %{command: {+0.0, +0.0}} =
               Blend.run(Blend.init(behaviours: []), inputs([], {0.0, 0.0, 0.0}))
    end

    test "a blend is a behaviour: nested blends give the flat blend's command" do
      scene = inputs(line({1.0, -0.3}, {1.0, 0.3}, 0.05), {0.3, 0.1, 0.2}, goal: {3.0, 0.0})

      flat =
        Blend.init(
          behaviours: [
            {:avoid, AvoidObstacles, []},
            {:go_to, GoToPoint, []},
            {:door, CrossDoor, []}
          ]
        )

      nested =
        Blend.init(
          behaviours: [
            {:avoid, AvoidObstacles, []},
            {:travel, Blend, [behaviours: [{:go_to, GoToPoint, []}, {:door, CrossDoor, []}]]}
          ]
        )

      %{command: {v1, w1}} = Blend.run(flat, scene)
      %{command: {v2, w2}, activations: %{travel: travel}} = Blend.run(nested, scene)
      assert_in_delta v1, v2, 1.0e-12
      assert_in_delta w1, w2, 1.0e-12
      assert travel == 1.0

      assert {^travel, %{v: _, w: _}} =
               Blend.evaluate(scene, Blend.init(behaviours: [{:go_to, GoToPoint, []}]))
    end

    test "refuses duplicate names, unknown unless: names and bad weights" do
      assert_raise ArgumentError, ~r/duplicate/, fn ->
        Blend.init(behaviours: [{:a, GoToPoint, []}, {:a, AvoidObstacles, []}])
      end

      assert_raise ArgumentError, ~r/no such behaviour/, fn ->
        Blend.init(behaviours: [{:a, GoToPoint, [], unless: [:b]}])
      end

      assert_raise ArgumentError, ~r/weight/, fn ->
        Blend.init(behaviours: [{:a, GoToPoint, [], weight: 1.5}])
      end
    end
  end

  describe "conflicting behaviours" do
    # a wall 1 m wide straight ahead, free on both sides, the goal right behind it
    @obstacle for i <- 0..20, do: {1.0, -0.5 + i * 0.05}
    @goal {2.5, 0.0}

    test "avoid and go-to do not average into a collision" do
      blend = Blend.init(behaviours: @go_to_unless_avoid)
      start = {0.65, 0.0, 0.0}
      scene = inputs(@obstacle, start, goal: @goal)

      # go-to wants straight on and fast, avoid wants to turn and stop
      assert {1.0, %{w: go_w}} = Behaviour.evaluate({GoToPoint, GoToPoint.init()}, scene)
      assert abs(Fuzzy.defuzzify(go_w)) < 1.0e-9

      %{command: {v, w}, activations: acts} = Blend.run(blend, scene)
      assert acts.avoid > 0.9
      assert acts.go_to < 0.1
      assert abs(w) > 0.3 * 2.0 or v < 0.1 * 0.5

      # the blended controller gets round; averaging the behaviours' crisp
      # commands drives into the wall from the same place
      assert {:reached, _, closest} = drive(blended(blend), @obstacle, start, %{goal: @goal})
      assert closest > @radius

      naive = naive_average([{AvoidObstacles, []}, {GoToPoint, []}])
      assert {:collision, _, _} = drive(naive, @obstacle, start, %{goal: @goal})

      # so does fuzzy blending without the context rule "go-to unless avoid":
      # it is the context, not only the single defuzzification, that settles it
      no_context = Blend.init(behaviours: [{:avoid, AvoidObstacles, []}, {:go_to, GoToPoint, []}])
      assert {:collision, _, _} = drive(blended(no_context), @obstacle, start, %{goal: @goal})
    end

    test "a symmetric obstacle does not deadlock: the tie breaks left and the robot gets past" do
      blend = Blend.init(behaviours: @go_to_unless_avoid)
      start = {0.0, 0.0, 0.0}
      {v, w} = blended(blend).(inputs(@obstacle, {0.5, 0.0, 0.0}, goal: @goal))
      assert w > 0.3 * 2.0
      assert v >= 0.0

      assert {:reached, _, closest} = drive(blended(blend), @obstacle, start, %{goal: @goal})
      assert closest > @radius
    end
  end

  describe "closed loop" do
    test "reaches a goal past a box without coming within its radius of any point" do
      box =
        line({1.5, -0.2}, {1.5, 0.2}, 0.1) ++
          line({1.9, -0.2}, {1.9, 0.2}, 0.1) ++
          line({1.5, 0.2}, {1.9, 0.2}, 0.1) ++ line({1.5, -0.2}, {1.9, -0.2}, 0.1)

      blend = Blend.init(behaviours: @go_to_unless_avoid)

      for start <- [{0.0, 0.0, 0.0}, {0.0, 0.15, 0.0}, {0.0, -0.3, 0.4}] do
        assert {:reached, steps, closest} = drive(blended(blend), box, start, %{goal: {3.5, 0.0}})
        assert closest > @radius
        assert steps < 300
      end
    end

    test "crosses a door in a wall, centred in it" do
      wall = line({2.0, -3.0}, {2.0, -0.45}, 0.05) ++ line({2.0, 0.45}, {2.0, 3.0}, 0.05)
      door = %{centre: {2.0, 0.0}, heading: 0.0, width: 0.9}

      blend =
        Blend.init(
          behaviours: [
            {:avoid, AvoidObstacles, []},
            {:cross_door, CrossDoor, []},
            {:go_to, GoToPoint, [], unless: [:avoid, :cross_door]}
          ]
        )

      for start <- [{0.0, 1.0, 0.0}, {0.0, -1.2, 0.3}] do
        assert {:reached, _, closest} =
                 drive(blended(blend), wall, start, %{goal: {4.0, 0.5}, door: door})

        # 0.45 m from each jamb is the centre line
        assert closest > 0.35
      end
    end
  end
end
