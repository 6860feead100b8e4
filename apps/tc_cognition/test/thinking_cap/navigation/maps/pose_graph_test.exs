defmodule ThinkingCap.Navigation.Maps.PoseGraphTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.Core.GridNif
  alias ThinkingCap.Navigation.EKF
  alias ThinkingCap.Navigation.Maps.PoseGraph
  alias ThinkingCap.Test.{DriftingCircle, LaserRoom}

  # the walls of a room, x in 0..w, y in 0..h, with a pillar so that no
  # symmetry makes two poses fit alike, as points every 5 cm
  defp room(w, h) do
    walls = [
      {{0.0, 0.0}, {w, 0.0}},
      {{w, 0.0}, {w, h}},
      {{w, h}, {0.0, h}},
      {{0.0, h}, {0.0, 0.0}},
      {{1.5, 1.0}, {2.0, 1.0}},
      {{2.0, 1.0}, {2.0, 1.8}}
    ]

    for {{x0, y0}, {x1, y1}} <- walls,
        n = max(1, round(:math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2) / 0.05)),
        k <- 0..n,
        do: {x0 + (x1 - x0) * k / n, y0 + (y1 - y0) * k / n}
  end

  defp bin(points),
    do: for({x, y} <- points, into: <<>>, do: <<x::float-native, y::float-native>>)

  # the points as seen from a pose (in its frame), those within 8 m
  defp seen(points, {x, y, th}) do
    {c, s} = {:math.cos(th), :math.sin(th)}

    points
    |> Enum.map(fn {px, py} -> {c * (px - x) + s * (py - y), -s * (px - x) + c * (py - y)} end)
    |> Enum.filter(fn {a, b} -> a * a + b * b < 64 end)
    |> Enum.take_every(3)
  end

  describe "slam_match (correlative scan matching)" do
    test "finds the true pose from a guess 0.25 m and 0.1 rad off" do
      walls = room(6.0, 4.0)
      truth = {3.1, 2.2, 0.4}
      query = bin(seen(walls, truth))

      {{x, y, th}, score, {cxx, _, _, cyy, _, ctt}, at_guess, false} =
        GridNif.slam_match(bin(walls), query, {3.3, 2.05, 0.5}, {0.5, 0.2}, 0.05, 0.05)

      assert_in_delta x, 3.1, 0.02
      assert_in_delta y, 2.2, 0.02
      assert_in_delta th, 0.4, 0.01
      assert score > 0.8
      assert at_guess < score - 0.3
      assert :math.sqrt(max(cxx, cyy)) < 0.05 and :math.sqrt(ctt) < 0.02
    end

    test "a wall on a border of the likelihood grid's cells is where it is, not half a cell off" do
      # the grid's origin lies a whole number of cells below the lowest
      # point: both walls fall on borders between its cells
      walls = for y <- [0.0, 2.0], k <- 0..400, do: {k * 0.025, y}
      truth = {5.0, 1.0, 0.0}
      query = bin(seen(walls, truth))

      {{_x, y, th}, _score, _cov, _at_guess, true} =
        GridNif.slam_match(bin(walls), query, truth, {0.3, 0.06}, 0.05, 0.05)

      # measured from the centres of the cells the points fall in: 12.5 mm
      assert_in_delta y, 1.0, 0.003
      assert_in_delta th, 0.0, 0.002
    end

    test "a corridor's length is not fixed: the spread along it is wide" do
      walls = for k <- 0..400, y <- [0.0, 1.5], do: {k * 0.05, y}

      query = bin(seen(walls, {10.0, 0.75, 0.0}))

      {_pose, _score, {cxx, _, _, cyy, _, _}, _at_guess, true} =
        GridNif.slam_match(bin(walls), query, {10.2, 0.75, 0.0}, {0.5, 0.1}, 0.05, 0.05)

      assert :math.sqrt(cxx) > 0.1
      assert :math.sqrt(cyy) < 0.05
    end

    test "in a corridor, a best pose on the border along it still fixes the place across it" do
      # 40 m long, 2 m wide, nothing along it within the laser's reach
      walls = for k <- 0..800, y <- [0.0, 2.0], do: {k * 0.05, y}
      query = bin(seen(walls, {20.0, 1.0, 0.0}))

      {{_x, y, th}, _score, {cxx, _, _, cyy, _, _}, at_guess, true} =
        GridNif.slam_match(bin(walls), query, {20.3, 1.2, 0.03}, {0.5, 0.1}, 0.05, 0.05)

      assert_in_delta y, 1.0, 0.02
      assert_in_delta th, 0.0, 0.01
      assert at_guess < 0.5
      assert :math.sqrt(cxx) > 0.1
      assert :math.sqrt(cyy) < 0.05
    end

    test "a best pose on the window's border is no match: the peak may lie beyond" do
      walls = room(6.0, 4.0)
      query = bin(seen(walls, {3.1, 2.2, 0.4}))
      # the truth 0.7 m from the guess, the window 0.4 m
      assert GridNif.slam_match(bin(walls), query, {3.8, 2.2, 0.4}, {0.4, 0.2}, 0.05, 0.05) ==
               :none
    end

    test "nothing to match against says so; bad arguments are refused" do
      assert GridNif.slam_match(<<>>, bin([{1.0, 0.0}]), {0.0, 0.0, 0.0}, {0.5, 0.1}, 0.05, 0.05) ==
               :none

      assert_raise ArgumentError, fn ->
        GridNif.slam_match(<<1, 2, 3>>, <<>>, {0.0, 0.0, 0.0}, {0.5, 0.1}, 0.05, 0.05)
      end
    end
  end

  describe "optimize/1" do
    # a square of side 4 m driven with a heading bias of 0.02 rad a node
    defp drifting_square do
      truth =
        for side <- 0..3, k <- 0..7 do
          th = side * :math.pi() / 2
          {sx, sy} = Enum.at([{0.0, 0.0}, {4.0, 0.0}, {4.0, 4.0}, {0.0, 4.0}], side)
          {sx + k * 0.5 * :math.cos(th), sy + k * 0.5 * :math.sin(th), th}
        end

      steps =
        Enum.chunk_every(truth, 2, 1, :discard) |> Enum.map(fn [a, b] -> EKF.relative(a, b) end)

      estimates =
        Enum.scan(steps, hd(truth), fn {dx, dy, dth}, pose ->
          EKF.motion(pose, {dx, dy, dth + 0.02})
        end)

      {truth, [hd(truth) | estimates]}
    end

    test "a loop edge pulls a drifted square back into shape" do
      {truth, estimates} = drifting_square()

      g =
        Enum.reduce(estimates, PoseGraph.new(), fn pose, g ->
          {_id, g} = PoseGraph.add_node(g, pose, nil, <<>>)
          g
        end)

      last = PoseGraph.last(g)
      err_before = distance(PoseGraph.pose(g, last), List.last(truth))
      assert err_before > 0.5

      # where the last node truly lies seen from the first
      z = EKF.relative(hd(truth), List.last(truth))

      loop = %{
        from: 0,
        to: last,
        z: z,
        info: {2500.0, 0.0, 0.0, 2500.0, 0.0, 10_000.0},
        kind: :loop
      }

      g = PoseGraph.optimize(%{g | edges: [loop | g.edges]})

      assert distance(PoseGraph.pose(g, last), List.last(truth)) < 0.1
      {x0, y0, _} = PoseGraph.pose(g, 0)
      assert abs(x0) + abs(y0) < 1.0e-9
    end

    test "a loop edge that contradicts the rest is dropped" do
      {_truth, estimates} = drifting_square()

      g =
        Enum.reduce(estimates, PoseGraph.new(), fn pose, g ->
          {_id, g} = PoseGraph.add_node(g, pose, nil, <<>>)
          g
        end)

      last = PoseGraph.last(g)

      wrong = %{
        from: 0,
        to: last,
        z: {9.0, -7.0, 2.0},
        info: {1.0e4, 0.0, 0.0, 1.0e4, 0.0, 1.0e4},
        kind: :loop
      }

      g = PoseGraph.optimize(%{g | edges: [wrong | g.edges]})

      refute Enum.any?(g.edges, &(&1.kind == :loop))
      assert_in_delta elem(PoseGraph.pose(g, last), 0), elem(List.last(estimates), 0), 1.0e-6
    end
  end

  describe "close_loop/2" do
    test "coming back into a room seen before closes the loop and undoes the drift" do
      walls = room(8.0, 6.0)

      # round the room's centre, the estimate drifting
      {truth, estimates} = DriftingCircle.poses(40)

      {g, closed} =
        DriftingCircle.drive(40, PoseGraph.new(loop_gap: 15), fn true_pose, estimate, g ->
          {id, g} = PoseGraph.add_node(g, estimate, nil, bin(seen(walls, true_pose)))

          case PoseGraph.close_loop(g, id) do
            {:closed, g, from, to} -> {g, {:closed, from, to}}
            {:none, g} -> {g, :none}
          end
        end)

      assert closed > 0
      last = PoseGraph.last(g)
      drifted = distance(List.last(estimates), List.last(truth))
      assert drifted > 0.3

      for id <- 0..last do
        assert distance(PoseGraph.pose(g, id), Enum.at(truth, id)) < 0.08
      end
    end
  end

  describe "close_loop/2, a large correction" do
    test "waits for a second node's match to say the same" do
      walls = room(8.0, 6.0)
      {truth, _} = DriftingCircle.poses(22)

      g =
        truth
        |> Enum.take(20)
        |> Enum.reduce(PoseGraph.new(loop_gap: 15), fn pose, g ->
          {_id, g} = PoseGraph.add_node(g, pose, nil, bin(seen(walls, pose)))
          g
        end)

      # the next two nodes 0.3 m off: a correction larger than 0.15 m
      off = fn {x, y, th} -> {x + 0.3, y, th} end
      t20 = Enum.at(truth, 20)
      {id, g} = PoseGraph.add_node(g, off.(t20), nil, bin(seen(walls, t20)))
      assert {:none, g} = PoseGraph.close_loop(g, id)

      t21 = Enum.at(truth, 21)
      {id, g} = PoseGraph.add_node(g, off.(t21), nil, bin(seen(walls, t21)))
      assert {:closed, g, _from, _to} = PoseGraph.close_loop(g, id)
      assert distance(PoseGraph.pose(g, id), t21) < 0.05
    end
  end

  describe "close_loop/2, the loop edge's heading" do
    # round a room and back to the start, 5 cm off: a loop edge
    defp loop_edge(opts) do
      walls = room(8.0, 6.0)
      {truth, _} = DriftingCircle.poses(21)

      g =
        truth
        |> Enum.take(20)
        |> Enum.reduce(PoseGraph.new([loop_gap: 15, local_nodes: 0] ++ opts), fn pose, g ->
          {_id, g} = PoseGraph.add_node(g, pose, nil, bin(seen(walls, pose)))
          g
        end)

      # (no node-to-node match: it would set the last node right first)
      {x, y, th} = t20 = Enum.at(truth, 20)
      {id, g} = PoseGraph.add_node(g, {x + 0.05, y, th}, nil, bin(seen(walls, t20)))
      {:closed, g, _, _} = PoseGraph.close_loop(g, id)
      Enum.find(g.edges, &(&1.kind == :loop))
    end

    test "is trusted loop_heading_scale times less than its match says" do
      %{info: {a1, _, _, d1, _, f1}} = loop_edge([])
      %{info: {a3, _, _, d3, _, f3}} = loop_edge(loop_heading_scale: 3.0)
      # the heading's information a ninth (σ three times), the place's about as it was
      assert_in_delta f3 * 9 / f1, 1.0, 0.02
      assert_in_delta a3 / a1, 1.0, 0.3
      assert_in_delta d3 / d1, 1.0, 0.3
    end
  end

  describe "close_loop/2 in a corridor" do
    # down a long corridor and back: the way back drifted 0.12 m across
    # it and 0.3 m along it
    defp corridor_and_back(across \\ 0.12) do
      walls = for k <- 0..800, y <- [0.0, 2.0], do: {k * 0.05, y}
      out = for k <- 0..39, do: {10.0 + k * 0.3, 1.0, 0.0}
      back = for k <- 0..15, do: {21.7 - k * 0.3, 1.0, :math.pi()}

      {g, results} =
        Enum.reduce(out ++ back, {PoseGraph.new(), []}, fn {x, y, th} = truth, {g, acc} ->
          # out: true; the first node back 0.3 m along and 0.12 m across
          # off; then each one step on from where the graph has the last
          estimate =
            cond do
              th == 0.0 -> truth
              x == 21.7 -> {x + 0.3, y + across, th}
              true -> EKF.motion(PoseGraph.pose(g, PoseGraph.last(g)), {0.3, 0.0, 0.0})
            end

          {id, g} = PoseGraph.add_node(g, estimate, nil, bin(seen(walls, truth)))

          case PoseGraph.close_loop(g, id) do
            {:closed, g, _from, _to} -> {g, [:closed | acc]}
            {:none, g} -> {g, [:none | acc]}
          end
        end)

      {g, results, back}
    end

    test "a match that would move the pose far across the corridor is refused" do
      # 0.25 m across: more than the localizer errs across a corridor
      {_g, results, _back} = corridor_and_back(0.25)
      refute :closed in results
    end

    test "fixes the place across the corridor and leaves it along as it was" do
      {g, results, back} = corridor_and_back()
      assert :closed in results
      {x, y, _} = PoseGraph.pose(g, PoseGraph.last(g))
      {tx, ty, _} = List.last(back)
      assert_in_delta y, ty, 0.03
      # along the corridor the scans say nothing: the drift stays
      assert_in_delta x, tx + 0.3, 0.1

      # the first way down is left where it was, but next to the turn
      # (where the jump between the two ways is shared out)
      for id <- 0..29 do
        {_, y0, _} = PoseGraph.pose(g, id)
        assert_in_delta y0, 1.0, 0.04
      end
    end
  end

  describe "the loop window" do
    # round the room's centre; each step the estimate slips 6 cm in x
    # from where the graph has the node before (heading true): 0.9 m
    # off by the time the loop can close
    defp slipping(walls, opts) do
      {truth, _} = DriftingCircle.poses(30)

      truth
      |> Enum.chunk_every(2, 1)
      |> Enum.with_index()
      |> Enum.reduce({PoseGraph.new(opts), 0}, fn {[true_pose | _], k}, {g, closed} ->
        estimate =
          case k do
            0 ->
              true_pose

            _ ->
              {px, py, _} = PoseGraph.pose(g, k - 1)
              {ax, ay, _} = Enum.at(truth, k - 1)
              {x, y, th} = true_pose
              {px + x - ax + 0.06, py + y - ay, th}
          end

        {id, g} = PoseGraph.add_node(g, estimate, nil, bin(seen(walls, true_pose)))

        case PoseGraph.close_loop(g, id) do
          {:closed, g, _from, _to} -> {g, closed + 1}
          {:none, g} -> {g, closed}
        end
      end)
    end

    test "grows with the way driven: a loop drifted beyond the least window closes" do
      walls = room(8.0, 6.0)
      # the nodes at the estimates: the scans matched only in loops
      common = [loop_gap: 15, window_angle_growth: 0.0, max_window: 1.5, local_nodes: 0]

      # beyond the least window, a match may fix the place across a
      # wall seen alone, but never undoes the drift along it
      {fixed, _closed} = slipping(walls, common ++ [window_growth: 0.0])
      {truth, _} = DriftingCircle.poses(30)
      assert distance(PoseGraph.pose(fixed, PoseGraph.last(fixed)), List.last(truth)) > 0.5

      {grown, closed} = slipping(walls, common ++ [window_growth: 0.25])
      assert closed > 0

      assert distance(PoseGraph.pose(grown, PoseGraph.last(grown)), List.last(truth)) <
               distance(PoseGraph.pose(fixed, PoseGraph.last(fixed)), List.last(truth)) / 4
    end
  end

  describe "add_node/4, the edge from the node before" do
    # across a room, 0.3 m a node, the estimates right but for the last
    # one's, 0.03 rad and 3 cm off (the localizer's jitter)
    defp jittered(opts) do
      walls = room(8.0, 6.0)
      truth = for k <- 0..6, do: {2.5 + 0.3 * k, 3.0 + 0.05 * k, 0.1}
      {x, y, th} = List.last(truth)
      estimates = Enum.drop(truth, -1) ++ [{x + 0.03, y - 0.02, th + 0.03}]

      g =
        Enum.zip(truth, estimates)
        |> Enum.reduce(PoseGraph.new(opts), fn {t, e}, g ->
          {_id, g} = PoseGraph.add_node(g, e, nil, bin(seen(walls, t)))
          g
        end)

      edge = Enum.find(g.edges, &(&1.from == 5 and &1.to == 6))
      {edge, EKF.relative(Enum.at(truth, 5), Enum.at(truth, 6))}
    end

    test "where the scan matches the nodes' before, the match makes the edge" do
      {%{z: {zx, zy, zth}, kind: :sequence}, {tx, ty, tth}} = jittered([])
      assert abs(zth - tth) < 0.005
      assert :math.sqrt((zx - tx) ** 2 + (zy - ty) ** 2) < 0.02
    end

    test "in a corridor the scan fixes the heading and the place across it, the estimate along it" do
      walls = for y <- [0.0, 2.0], k <- 0..400, do: {k * 0.05, y}
      truth = for k <- 0..6, do: {5.0 + 0.3 * k, 1.0, 0.0}
      # the last estimate 0.1 m too far along, 5 cm across, 0.03 rad turned
      estimates = Enum.drop(truth, -1) ++ [{6.9, 1.05, 0.03}]

      g =
        Enum.zip(truth, estimates)
        |> Enum.reduce(PoseGraph.new(), fn {t, e}, g ->
          {_id, g} = PoseGraph.add_node(g, e, nil, bin(seen(walls, t)))
          g
        end)

      assert %{z: {zx, zy, zth}, via: :corridor} =
               Enum.find(g.edges, &(&1.from == 5 and &1.to == 6))

      assert_in_delta zx, 0.4, 0.005
      assert_in_delta zy, 0.0, 0.01
      assert_in_delta zth, 0.0, 0.003
    end

    test "an estimate a tenth of a radian off, as in a fast turn, is still matched" do
      walls = room(8.0, 6.0)
      truth = for k <- 0..6, do: {2.5 + 0.3 * k, 3.0, 0.1 + 0.05 * k}
      {x, y, th} = List.last(truth)
      estimates = Enum.drop(truth, -1) ++ [{x, y, th - 0.1}]

      g =
        Enum.zip(truth, estimates)
        |> Enum.reduce(PoseGraph.new(), fn {t, e}, g ->
          {_id, g} = PoseGraph.add_node(g, e, nil, bin(seen(walls, t)))
          g
        end)

      assert %{z: {_, _, zth}, via: :match} = Enum.find(g.edges, &(&1.from == 5 and &1.to == 6))
      assert_in_delta zth, 0.05, 0.005
    end

    test "with local_nodes: 0 the estimate alone makes it, jitter and all" do
      {%{z: {_, _, zth}}, {_, _, tth}} = jittered(local_nodes: 0)
      assert_in_delta zth - tth, 0.03, 1.0e-6
    end
  end

  describe "add_node/4, the chain of scan matches" do
    # rooms in a row along a hall, with a pillar and a box
    @hall [
      {{0.0, 0.0}, {12.0, 0.0}},
      {{12.0, 0.0}, {12.0, 5.0}},
      {{12.0, 5.0}, {0.0, 5.0}},
      {{0.0, 5.0}, {0.0, 0.0}},
      {{3.0, 0.0}, {3.0, 1.8}},
      {{3.0, 3.2}, {3.0, 5.0}},
      {{7.0, 0.0}, {7.0, 2.0}},
      {{7.0, 3.0}, {7.0, 5.0}},
      {{5.0, 4.2}, {5.6, 4.2}},
      {{9.5, 0.8}, {10.0, 0.8}},
      {{10.0, 0.8}, {10.0, 1.3}}
    ]

    # 11 m through the rooms, 0.3 m a node, a 181-beam laser 5 cm ahead
    # of the centre; the estimates jitter (±1 cm, ±5 mrad) round the
    # truth, as the localizer's do, and turn away from it by `bias` rad a
    # node; the ranges have Gaussian noise of σ `noise` m
    defp chain(opts, seed, bias \\ 0.0, noise \\ 0.0) do
      rng = :rand.seed_s(:exsss, {seed, 2, 3})

      truth =
        for k <- 0..36, do: {1.0 + 0.3 * k, 2.5 + 0.4 * :math.sin(k / 6), 0.13 * :math.cos(k / 6)}

      {g, _} =
        Enum.reduce(truth, {PoseGraph.new(opts), rng}, fn {x, y, th} = t, {g, rng} ->
          {[u, v, w], rng} = Enum.map_reduce(1..3, rng, fn _, r -> :rand.uniform_s(r) end)

          est =
            if g.next == 0,
              do: t,
              else:
                {x + 0.02 * (u - 0.5), y + 0.02 * (v - 0.5),
                 th + bias * g.next + 0.01 * (w - 0.5)}

          laser = {x + 0.05 * :math.cos(th), y + 0.05 * :math.sin(th), th}
          scan = LaserRoom.scan(@hall, laser)

          {ranges, rng} =
            Enum.map_reduce(scan.ranges, rng, fn
              r, rng when noise == 0.0 ->
                {r, rng}

              r, rng ->
                {n, rng} = :rand.normal_s(rng)
                {r + noise * n, rng}
            end)

          scan = %{scan | ranges: ranges}

          {_id, g} =
            PoseGraph.add_node(g, est, nil, PoseGraph.scan_points(scan, {0.05, 0.0, 0.0}, 2))

          {g, rng}
        end)

      # where the chain of edges from the first node puts the last
      end_pose =
        g.edges
        |> Enum.filter(&(&1.to == &1.from + 1))
        |> Enum.sort_by(& &1.to)
        |> Enum.reduce(hd(truth), fn e, p -> EKF.motion(p, e.z) end)

      {end_pose, List.last(truth)}
    end

    test "its edges drift a few centimetres over 11 m where the estimates jitter" do
      for seed <- 1..5 do
        {{x, y, th}, {tx, ty, tth}} = chain([], seed)
        assert :math.sqrt((x - tx) ** 2 + (y - ty) ** 2) < 0.05
        assert abs(th - tth) < 0.01
      end
    end

    # an odometry whose wheelbase is 0.5 % off turns the localizer's
    # estimate a few mrad a node away from the walls; a match fixes the
    # heading less sharply than 0.01 rad through 1 cm of range noise, but
    # it still holds the chain (with a 0.01 rad gate: 0.16-0.23 m, 8-30
    # mrad off on these seeds)
    test "the chain holds the heading where the estimates turn away from it" do
      for seed <- 1..4 do
        {{x, y, th}, {tx, ty, tth}} = chain([], seed, 0.003, 0.01)
        assert :math.sqrt((x - tx) ** 2 + (y - ty) ** 2) < 0.1
        assert abs(th - tth) < 0.02
      end
    end
  end

  test "dense_points/3 joins neighbours no farther apart than the gap" do
    points = bin([{0.0, 0.0}, {0.1, 0.0}, {0.5, 0.0}])

    dense =
      for <<x::float-native, y::float-native <- PoseGraph.dense_points(points, 0.025, 0.3)>>,
        do: {x, y}

    # 0 to 0.1 every 2.5 cm; 0.1 to 0.5 is a gap: its far end alone
    assert Enum.map(dense, fn {x, _} -> Float.round(x, 4) end) == [
             0.0,
             0.025,
             0.05,
             0.075,
             0.1,
             0.5
           ]

    assert Enum.all?(dense, fn {_, y} -> y == 0.0 end)
    assert PoseGraph.dense_points(<<>>, 0.025, 0.3) == <<>>
  end

  test "scan_points/3: the endpoints with an echo, in the robot's frame" do
    scan = %{ranges: [1.0, 8.0, 2.0], angle_min: -0.5, angle_increment: 0.5, range_max: 8.0}
    points = PoseGraph.scan_points(scan, {0.1, 0.0, 0.0})
    assert [{x1, y1}, {x2, y2}] = for(<<x::float-native, y::float-native <- points>>, do: {x, y})
    assert_in_delta x1, 0.1 + :math.cos(-0.5), 1.0e-9
    assert_in_delta y1, :math.sin(-0.5), 1.0e-9
    assert_in_delta x2, 0.1 + 2 * :math.cos(0.5), 1.0e-9
    assert_in_delta y2, 2 * :math.sin(0.5), 1.0e-9
  end

  defp distance({x1, y1, _}, {x2, y2, _}), do: :math.sqrt((x1 - x2) ** 2 + (y1 - y2) ** 2)
end
