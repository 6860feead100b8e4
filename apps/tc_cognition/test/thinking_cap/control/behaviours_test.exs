defmodule ThinkingCap.Control.BehavioursTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.{
    AvoidObstacles,
    Behaviour,
    CrossDoor,
    FollowPath,
    FollowWall,
    Fuzzy,
    Geometry,
    GoToPoint
  }

  alias ThinkingCap.Perception.LPS

  @vmax 0.5
  @wmax 2.0
  @pi :math.pi()

  # robot-frame obstacle points around a robot at the world origin
  defp inputs(points, overrides \\ []) do
    Map.merge(
      %{
        lps: LPS.from_points(points),
        pose: {0.0, 0.0, 0.0},
        goal: nil,
        path: nil,
        door: nil,
        limits: %{max_speed: @vmax, max_turn_rate: @wmax},
        radius: 0.2
      },
      Map.new(overrides)
    )
  end

  # {context, v, w} of a behaviour; v/w nil when it has no opinion
  defp run(module, params, inputs) do
    {context, outputs} = Behaviour.evaluate({module, module.init(params)}, inputs)
    crisp = fn var -> outputs[var] && Fuzzy.defuzzify(outputs[var]) end
    {context, crisp.(:v), crisp.(:w)}
  end

  defp line({x0, y0}, {x1, y1}, step \\ 0.05) do
    n = max(1, round(:math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2) / step))
    for i <- 0..n, do: {x0 + (x1 - x0) * i / n, y0 + (y1 - y0) * i / n}
  end

  describe "the shared control variables" do
    test "terms scale with the limits; their centroids order as their names" do
      [v, w] = Behaviour.output_variables(%{max_speed: @vmax, max_turn_rate: @wmax})
      assert v.universe == {-0.25 * @vmax, @vmax}
      assert w.universe == {-@wmax, @wmax}

      centroid = fn var, term ->
        Fuzzy.defuzzify(
          Fuzzy.evaluate([[if: true, then: [{var.name, term}]]], %{}, [var])[var.name]
        )
      end

      speeds = Enum.map([:back, :stop, :slow, :medium, :fast], &centroid.(v, &1))
      assert speeds == Enum.sort(speeds)
      assert_in_delta centroid.(v, :stop), 0.0, 1.0e-12
      assert_in_delta centroid.(v, :slow), 0.25 * @vmax, 1.0e-9

      turns = Enum.map([:hard_right, :right, :straight, :left, :hard_left], &centroid.(w, &1))
      assert turns == Enum.sort(turns)
      assert_in_delta centroid.(w, :straight), 0.0, 1.0e-12
      assert_in_delta centroid.(w, :left), -centroid.(w, :right), 1.0e-9
    end

    test "every rule base is valid against its variables" do
      outs = Behaviour.output_variables(%{max_speed: 1, max_turn_rate: 1})
      avoid = AvoidObstacles.init()

      for side <- [:left, :right] do
        assert :ok =
                 Fuzzy.validate(
                   AvoidObstacles.rules(side),
                   AvoidObstacles.variables(avoid, 5) ++ outs
                 )
      end

      assert :ok = Fuzzy.validate(FollowWall.rules(), FollowWall.variables(5) ++ outs)

      assert :ok =
               Fuzzy.validate(
                 Behaviour.mirror(FollowWall.rules()),
                 FollowWall.variables(5) ++ outs
               )

      assert :ok =
               Fuzzy.validate(GoToPoint.rules(), GoToPoint.variables(GoToPoint.init()) ++ outs)

      assert :ok = Fuzzy.validate(CrossDoor.rules(), CrossDoor.variables() ++ outs)
    end
  end

  describe "AvoidObstacles" do
    test "slows for an obstacle ahead, the more the nearer, and applies then" do
      {c_none, v_none, _} = run(AvoidObstacles, [], inputs([]))
      {c_far, v_far, _} = run(AvoidObstacles, [], inputs([{1.0, 0.0}]))
      {c_near, v_near, _} = run(AvoidObstacles, [], inputs(line({0.4, -0.1}, {0.4, 0.1})))
      {c_touch, v_touch, _} = run(AvoidObstacles, [], inputs(line({0.3, -0.1}, {0.3, 0.1})))

      assert c_none == 0.0
      assert c_far < 0.2
      assert c_near > 0.7
      assert c_touch == 1.0
      assert v_near < v_far and v_far <= v_none
      assert v_near < 0.25 * @vmax
      assert abs(v_touch) < 0.02
    end

    test "turns away from an obstacle on the left, and on the right" do
      {_, _, w_left} = run(AvoidObstacles, [], inputs([{0.2, 0.35}]))
      {_, _, w_right} = run(AvoidObstacles, [], inputs([{0.2, -0.35}]))
      assert w_left < -0.1 * @wmax
      assert w_right > 0.1 * @wmax

      # in its way, a little to one side: turn to the other side
      {_, _, w_left} = run(AvoidObstacles, [], inputs([{0.45, 0.15}]))
      {_, _, w_right} = run(AvoidObstacles, [], inputs([{0.45, -0.15}]))
      assert w_left < -0.3 * @wmax
      assert w_right > 0.3 * @wmax
    end

    test "a symmetric obstacle dead ahead: turns left (ties break to the left), never straight" do
      scene = inputs(line({0.5, -0.3}, {0.5, 0.3}))
      assert AvoidObstacles.freer_side(scene, AvoidObstacles.init()) == :left
      {_, _, w} = run(AvoidObstacles, [], scene)
      assert w > 0.3 * @wmax

      # the right must be freer by more than the tie margin to win
      scene = inputs(line({0.5, -0.3}, {0.5, 0.3}) ++ [{0.25, 0.3}])
      assert AvoidObstacles.freer_side(scene, AvoidObstacles.init()) == :right
      assert {_, _, w} = run(AvoidObstacles, [], scene)
      assert w < -0.3 * @wmax
    end

    test "a side that touches the robot beside it, past its 70 degrees, is not the freer side" do
      # the LPS of a robot pressed against a door jamb (office, seed 4):
      # the jamb at 73 and 77 degrees on its left, touching; a wall a
      # metre off on its right. Seeing its left free it turned into the
      # jamb, and crossing the door kept it creeping forwards.
      at = fn d, a -> {d * :math.cos(a), d * :math.sin(a)} end
      jamb = [at.(0.158, 1.27), at.(0.255, 1.35)]
      wall = [at.(1.0, -0.8)]
      scene = inputs(jamb ++ wall)
      assert AvoidObstacles.freer_side(scene, AvoidObstacles.init()) == :right
      assert {_, _, w} = run(AvoidObstacles, [], scene)
      assert w < -0.3 * @wmax

      # the jamb 10 cm off the robot's edge: the sides' 70 degrees decide
      near = [at.(0.3, 1.27)]
      assert AvoidObstacles.freer_side(inputs(near ++ wall), AvoidObstacles.init()) == :left
    end

    test "a planned path that turns off to one side says which side to go round by" do
      # a pillar ahead and another on the left: the right is the freer side
      pillar = line({0.45, -0.1}, {0.45, 0.1}) ++ [{0.25, 0.3}]
      assert AvoidObstacles.freer_side(inputs(pillar), AvoidObstacles.init()) == :right

      # the path goes off to the left (through a gap beside the pillar):
      # round it by the left, where there is room
      left_path = [{0.0, 0.0}, {0.3, 0.5}, {0.6, 1.0}]
      scene = inputs(pillar, path: left_path)
      assert AvoidObstacles.freer_side(scene, AvoidObstacles.init()) == :left
      assert {_, _, w} = run(AvoidObstacles, [], scene)
      assert w > 0.3 * @wmax

      # not where the left has no room for the robot; nor for a path
      # straight on, past the pillar
      walled = pillar ++ line({0.05, 0.25}, {0.4, 0.25})

      assert AvoidObstacles.freer_side(inputs(walled, path: left_path), AvoidObstacles.init()) ==
               :right

      straight = [{0.0, 0.0}, {1.0, 0.05}, {2.0, 0.1}]

      assert AvoidObstacles.freer_side(inputs(pillar, path: straight), AvoidObstacles.init()) ==
               :right
    end

    test "at the end of a dead-end alley a turn under way holds until the way is free" do
      # an alley 0.7 m wide (walls at y = ±0.35 in the world), its end at
      # x = 0.4; the robot at the origin turns in place, heading th
      walls = line({-2.0, 0.35}, {0.4, 0.35}) ++ line({-2.0, -0.35}, {0.4, -0.35})
      walls = walls ++ line({0.4, -0.35}, {0.4, 0.35})

      seen = fn th ->
        for {x, y} <- walls,
            do: {x * :math.cos(th) + y * :math.sin(th), -x * :math.sin(th) + y * :math.cos(th)}
      end

      avoid = AvoidObstacles.init()

      # turning right, blocked: it keeps turning right, heading by heading,
      # until it faces back down the alley (the way ahead free)
      sides =
        for step <- 0..12 do
          th = -step * @pi / 12
          scene = inputs(seen.(th), last: {0.0, -1.5})
          free? = Geometry.ahead(scene.lps, 0.2, avoid.margin) >= avoid.slow
          {free?, AvoidObstacles.freer_side(scene, avoid)}
        end

      {blocked, _free} = Enum.split_while(sides, fn {free?, _} -> not free? end)
      assert length(blocked) >= 6
      assert Enum.all?(blocked, fn {_, side} -> side == :right end)

      # chosen afresh (no turn under way) the same headings do not agree
      # on a side: turning in place, the robot would go back and forth
      afresh =
        for step <- 0..(length(blocked) - 1),
            do: AvoidObstacles.freer_side(inputs(seen.(-step * @pi / 12)), avoid)

      assert Enum.uniq(afresh) |> length() == 2

      # a slow turn, or a free way ahead, is chosen afresh
      assert AvoidObstacles.freer_side(inputs(seen.(0.0), last: {0.0, -0.2}), avoid) == :left
      open = inputs(line({1.5, -0.3}, {1.5, 0.3}), last: {0.2, -1.5})
      assert AvoidObstacles.freer_side(open, avoid) == :left
    end

    test "obstacles behind or well to the side are no concern" do
      assert {+0.0, _, _} = run(AvoidObstacles, [], inputs(line({-0.4, -0.5}, {-0.4, 0.5})))
      assert {+0.0, _, _} = run(AvoidObstacles, [], inputs([{0.3, 1.0}, {0.3, -1.0}]))
    end
  end

  describe "FollowWall" do
    test "keeps its distance to a left wall: too close turns away, too far turns towards" do
      {c, v, w_close} = run(FollowWall, [side: :left], inputs(line({-2, 0.3}, {2, 0.3})))
      {_, _, w_ok} = run(FollowWall, [side: :left], inputs(line({-2, 0.5}, {2, 0.5})))
      {_, _, w_far} = run(FollowWall, [side: :left], inputs(line({-2, 0.7}, {2, 0.7})))

      assert c == 1.0
      assert v > 0.2 * @vmax
      assert w_close < -0.2 * @wmax
      assert abs(w_ok) < 0.05 * @wmax
      assert w_far > 0.2 * @wmax
    end

    test "mirrored for a right wall" do
      {_, _, w_close} = run(FollowWall, [side: :right], inputs(line({-2, -0.3}, {2, -0.3})))
      {_, _, w_far} = run(FollowWall, [side: :right], inputs(line({-2, -0.7}, {2, -0.7})))
      assert w_close > 0.2 * @wmax
      assert w_far < -0.2 * @wmax
    end

    test "at the right distance but heading into the wall: turns to run parallel" do
      # a left wall 0.5 m away abeam, closing in ahead (the robot heads 0.3 rad into it)
      points = for i <- 0..60, x = -1.0 + i * 0.05, do: {x, 0.5 - :math.tan(0.3) * x}
      {_, _, w} = run(FollowWall, [side: :left, distance: 0.5], inputs(points))
      assert w < -0.1 * @wmax
    end

    test "reads the LPS's wall segments when it has them" do
      lps = %{LPS.empty() | segments: [{{-2.0, 0.3}, {2.0, 0.3}}]}
      {c, _, w} = run(FollowWall, [side: :left], inputs([], lps: lps))
      assert c == 1.0
      assert w < -0.2 * @wmax
    end

    test "an inner corner: a wall ahead makes it slow and turn away from its wall" do
      points = line({-2, 0.5}, {0.6, 0.5}) ++ line({0.5, 0.5}, {0.5, -1.0})
      {_, v, w} = run(FollowWall, [side: :left], inputs(points))
      assert v < 0.3 * @vmax
      assert w < -0.4 * @wmax
    end

    test ":nearest follows the nearer wall; no wall near, no context" do
      # right wall at 0.7 (too far: turn right, towards it), left wall at 0.9
      {_, _, w} =
        run(FollowWall, [], inputs(line({-2, -0.7}, {2, -0.7}) ++ line({-2, 0.9}, {2, 0.9})))

      assert w < -0.2 * @wmax

      assert {+0.0, nil, nil} = run(FollowWall, [side: :left], inputs([]))
      assert {+0.0, _, _} = run(FollowWall, [side: :left], inputs(line({-2, 1.2}, {2, 1.2})))

      assert_raise ArgumentError, ~r/side/, fn -> FollowWall.init(side: :up) end
    end
  end

  describe "CrossDoor" do
    @door %{centre: {2.0, 0.0}, heading: 0.0, width: 0.9}

    test "heads for a door offset to the side" do
      {c, _, w} = run(CrossDoor, [], inputs([], door: %{@door | centre: {1.5, 0.6}}))
      assert c > 0.5
      assert w > 0.3 * @wmax

      {_, _, w} = run(CrossDoor, [], inputs([], door: %{@door | centre: {1.5, -0.6}}))
      assert w < -0.3 * @wmax
    end

    test "lines up with the door's heading, and drives straight through when lined up" do
      # on the axis, but facing 0.5 rad to the left of it
      {_, _, w} =
        run(CrossDoor, [], inputs([], door: %{@door | centre: {1.5, 0.0}}, pose: {0.0, 0.0, 0.5}))

      assert w < -0.3 * @wmax

      {c, v, w} = run(CrossDoor, [], inputs([], door: %{@door | centre: {1.2, 0.0}}))
      assert c == 1.0
      assert abs(w) < 1.0e-9
      assert v > 0.4 * @vmax
    end

    test "off the axis, it slows down near the door, not far before it" do
      # 0.12 m to the left of the axis of a 0.8 m door, facing along it
      door = %{centre: {0.4, -0.12}, heading: 0.0, width: 0.8}
      {_, v_near, _} = run(CrossDoor, [], inputs([], door: door))
      {_, v_far, _} = run(CrossDoor, [], inputs([], door: %{door | centre: {1.6, -0.12}}))
      assert v_near < 0.3 * @vmax
      assert v_far > 0.35 * @vmax

      # without the funnel, as slow far as near
      {_, v_far_strict, _} =
        run(CrossDoor, [funnel: 0.0], inputs([], door: %{door | centre: {1.6, -0.12}}))

      assert v_far_strict < 0.3 * @vmax
    end

    test "applies to a door near and ahead only, that the robot fits through" do
      assert {+0.0, nil, nil} = run(CrossDoor, [], inputs([]))
      # crossed
      assert {+0.0, _, _} = run(CrossDoor, [], inputs([], door: @door, pose: {2.6, 0.0, 0.0}))
      # ahead, but to be crossed the other way (it is behind the robot's path)
      assert {+0.0, _, _} = run(CrossDoor, [], inputs([], door: @door, pose: {0.0, 0.0, @pi}))
      # far
      assert {+0.0, _, _} = run(CrossDoor, [], inputs([], door: %{@door | centre: {6.0, 0.0}}))
      # too narrow for a 0.4 m robot
      assert {+0.0, _, _} = run(CrossDoor, [], inputs([], door: %{@door | width: 0.38}))
      # in the doorway: still crossing
      assert {1.0, _, _} = run(CrossDoor, [], inputs([], door: @door, pose: {2.1, 0.05, 0.1}))
    end

    test "a door without a heading is crossed from where the robot is" do
      {c, _, w} = run(CrossDoor, [], inputs([], door: %{centre: {1.5, 0.5}, width: 0.9}))
      assert c > 0.9
      assert_in_delta w, run(GoToPoint, [], inputs([], goal: {1.5, 0.5})) |> elem(2), 1.0e-9
      assert w > 0.2 * @wmax
    end

    test "prefers the door the LPS sees near the planned one" do
      lps = %{LPS.empty() | doors: [%{centre: {1.5, 0.35}, width: 0.9, heading: @pi}]}
      {_, _, w} = run(CrossDoor, [], inputs([], lps: lps, door: %{@door | centre: {1.5, 0.0}}))
      assert w > 0.2 * @wmax

      # too far from the planned door: ignored
      lps = %{LPS.empty() | doors: [%{centre: {1.5, 1.5}, width: 0.9, heading: 0.0}]}
      {_, _, w} = run(CrossDoor, [], inputs([], lps: lps, door: %{@door | centre: {1.5, 0.0}}))
      assert abs(w) < 1.0e-9
    end
  end

  describe "GoToPoint" do
    test "turns towards a goal behind and to the left (on the spot), or right" do
      {c, v, w} = run(GoToPoint, [], inputs([], goal: {-1.0, 1.0}))
      assert c == 1.0
      assert w > 0.7 * @wmax
      assert abs(v) < 0.01

      {_, _, w} = run(GoToPoint, [], inputs([], goal: {-1.0, -1.0}))
      assert w < -0.7 * @wmax

      # exactly behind: bearing +π, turns left
      {_, _, w} = run(GoToPoint, [], inputs([], goal: {-1.0, 0.0}))
      assert w > 0.7 * @wmax
    end

    test "slows down near the goal and stops applying once there" do
      speed = fn x -> run(GoToPoint, [], inputs([], goal: {x, 0.0})) |> elem(1) end
      assert speed.(0.3) < speed.(0.7)
      assert speed.(0.7) < speed.(3.0)
      assert speed.(3.0) > 0.8 * @vmax
      assert speed.(0.3) < 0.3 * @vmax

      assert {+0.0, _, _} = run(GoToPoint, [], inputs([], goal: {0.05, 0.0}))
      assert {+0.0, nil, nil} = run(GoToPoint, [], inputs([]))
    end

    test "the goal is in the world frame" do
      # facing +y from (1, 1): a goal at (1, 3) is straight ahead, one at (0, 1) on the left
      {_, v, w} = run(GoToPoint, [], inputs([], pose: {1.0, 1.0, @pi / 2}, goal: {1.0, 3.0}))
      assert abs(w) < 1.0e-9
      assert v > 0.8 * @vmax
      {_, _, w} = run(GoToPoint, [], inputs([], pose: {1.0, 1.0, @pi / 2}, goal: {0.0, 1.0}))
      assert w > 0.7 * @wmax
    end
  end

  describe "FollowPath" do
    test "heads to the lookahead point" do
      path = [{0.0, 0.0}, {1.0, 0.0}, {1.0, 2.0}]
      # before the corner, the lookahead point is round it, to the left
      {c, _, w} = run(FollowPath, [lookahead: 0.6], inputs([], path: path, pose: {0.8, 0.0, 0.0}))
      assert c == 1.0
      assert w > 0.5 * @wmax

      # far from the corner: straight on, fast
      {_, v, w} =
        run(FollowPath, [], inputs([], path: [{0.0, 0.0}, {4.0, 0.0}], pose: {0.5, 0.0, 0.0}))

      assert abs(w) < 1.0e-9
      assert v > 0.8 * @vmax

      # off to the right of the path: back towards it
      {_, _, w} =
        run(FollowPath, [], inputs([], path: [{0.0, 0.0}, {4.0, 0.0}], pose: {0.5, -0.4, 0.0}))

      assert w > 0.2 * @wmax
    end

    test "slows near the end of the path, not near the lookahead point, and ends there" do
      path = [{0.0, 0.0}, {4.0, 0.0}]
      {_, v_mid, _} = run(FollowPath, [], inputs([], path: path, pose: {1.0, 0.0, 0.0}))
      {_, v_end, _} = run(FollowPath, [], inputs([], path: path, pose: {3.7, 0.0, 0.0}))
      assert v_mid > 0.8 * @vmax
      assert v_end < 0.3 * @vmax

      assert {+0.0, _, _} = run(FollowPath, [], inputs([], path: path, pose: {3.98, 0.0, 0.0}))
      assert {+0.0, nil, nil} = run(FollowPath, [], inputs([]))
    end
  end
end
