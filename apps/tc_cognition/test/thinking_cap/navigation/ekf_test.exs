defmodule ThinkingCap.Navigation.EKFTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.EKF
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @beacons %{b1: {0.0, 0.0}, b2: {8.0, 0.0}, b3: {8.0, 8.0}, b4: {0.0, 8.0}, b5: {4.0, 9.0}}
  @noise [slip: 0.02, turn_slip: 0.03, drift: 0.02, floor: {0.001, 0.001}]
  @sensor {0.02, 0.02}

  defp gauss(rng, sd) do
    {n, rng} = :rand.normal_s(rng)
    {sd * n, rng}
  end

  # a robot driving a wavy loop around the middle of the beacons, its
  # encoders slipping, a beacon laser seeing every beacon at every step
  defp drive(ekf, rng, steps) do
    truth = {4.0, 2.0, 0.0}
    odom = {0.0, 0.0, 0.0}
    dt = 0.1

    Enum.reduce(1..steps, {ekf, truth, odom, rng}, fn i, {ekf, truth, odom, rng} ->
      v = 0.4
      w = 0.25 + 0.2 * :math.sin(i / 20)
      true_delta = {v * dt, 0.0, w * dt}
      {ns, rng} = gauss(rng, 0.02 * :math.sqrt(v * dt))
      {nt, rng} = gauss(rng, 0.03 * :math.sqrt(abs(w * dt)))
      # the encoders report the motion the wheels would have made without slip
      odom_delta = {v * dt + ns, 0.0, w * dt + nt}
      truth = EKF.motion(truth, true_delta)
      new_odom = EKF.motion(odom, odom_delta)

      ekf = EKF.predict(ekf, EKF.relative(odom, new_odom), @noise)

      {detections, rng} =
        Enum.map_reduce(@beacons, rng, fn {id, at}, rng ->
          {r, b} = EKF.measure(truth, at)
          {nr, rng} = gauss(rng, 0.02)
          {nb, rng} = gauss(rng, 0.02)
          {%{id: id, range: r + nr, bearing: normalize_angle(b + nb)}, rng}
        end)

      {ekf, _used, _rejected} = EKF.update_beacons(ekf, detections, @beacons, @sensor)
      {ekf, truth, new_odom, rng}
    end)
  end

  defp errors(%EKF{pose: {x, y, th}}, {tx, ty, tth}),
    do: {x - tx, y - ty, normalize_angle(th - tth)}

  describe "convergence" do
    for seed <- [1, 7, 42] do
      test "from a pose 1 m and 0.3 rad off (seed #{seed})" do
        rng = :rand.seed_s(:exsss, unquote(seed))
        # truth starts at {4, 2, 0}: the filter believes 0.8 m, 0.6 m and 0.3 rad off
        ekf = EKF.new({4.8, 1.4, 0.3}, EKF.diagonal(1.0, 1.0, 0.5))
        {sx0, sy0, sth0} = EKF.sigmas(ekf)
        {ekf, truth, _odom, _rng} = drive(ekf, rng, 150)

        {ex, ey, eth} = errors(ekf, truth)
        {sx, sy, sth} = EKF.sigmas(ekf)

        assert :math.sqrt(ex * ex + ey * ey) < 0.05
        assert abs(eth) < 0.02
        assert sx < sx0 / 20 and sy < sy0 / 20 and sth < sth0 / 20
        # consistent: the error is within 3 sigma
        assert abs(ex) < 3 * sx
        assert abs(ey) < 3 * sy
        assert abs(eth) < 3 * sth
      end
    end
  end

  describe "update_beacon/5" do
    setup do
      ekf = EKF.new({2.0, 3.0, 0.5}, EKF.diagonal(0.05, 0.05, 0.02))
      %{ekf: ekf}
    end

    test "a consistent detection is accepted and shrinks the covariance", %{ekf: ekf} do
      {r, b} = EKF.measure({2.0, 3.0, 0.5}, {6.0, 4.0})

      assert {:accepted, updated, d2} =
               EKF.update_beacon(ekf, %{range: r + 0.01, bearing: b}, {6.0, 4.0}, @sensor)

      assert d2 < 1.0
      {sx, sy, _} = EKF.sigmas(updated)
      {sx0, sy0, _} = EKF.sigmas(ekf)
      assert sx * sy < sx0 * sy0
    end

    test "an outlier is rejected by the Mahalanobis gate and changes nothing", %{ekf: ekf} do
      {r, b} = EKF.measure({2.0, 3.0, 0.5}, {6.0, 4.0})

      assert {:rejected, ^ekf, d2} =
               EKF.update_beacon(ekf, %{range: r + 1.5, bearing: b}, {6.0, 4.0}, @sensor)

      assert d2 > 13.8

      assert {:rejected, ^ekf, _} =
               EKF.update_beacon(ekf, %{range: r, bearing: b + 0.6}, {6.0, 4.0}, @sensor)

      # the same reading passes with the gate open
      assert {:accepted, _, _} =
               EKF.update_beacon(ekf, %{range: r + 1.5, bearing: b}, {6.0, 4.0}, @sensor,
                 gate: :infinity
               )
    end

    test "the bearing innovation is normalised across ±π" do
      # the beacon straight behind: predicted bearing π, measured −π + 0.01
      ekf = EKF.new({0.0, 0.0, 0.0}, EKF.diagonal(0.05, 0.05, 0.05))

      assert {:accepted, updated, d2} =
               EKF.update_beacon(
                 ekf,
                 %{range: 3.0, bearing: -:math.pi() + 0.01},
                 {-3.0, 0.0},
                 @sensor
               )

      assert d2 < 1.0
      {_, _, th} = updated.pose
      assert abs(th) < 0.02
    end

    test "update_beacons/5 associates by id and ignores unknown beacons", %{ekf: ekf} do
      beacons = %{a: {6.0, 4.0}, b: {2.0, 8.0}}
      {ra, ba} = EKF.measure(ekf.pose, beacons.a)
      {rb, bb} = EKF.measure(ekf.pose, beacons.b)

      detections = [
        %{id: :b, range: rb, bearing: bb},
        %{id: :nowhere, range: 1.0, bearing: 0.0},
        %{id: :a, range: ra + 3.0, bearing: ba}
      ]

      assert {updated, 1, [:a]} = EKF.update_beacons(ekf, detections, beacons, @sensor)
      {_, sy, _} = EKF.sigmas(updated)
      {_, sy0, _} = EKF.sigmas(ekf)
      # b is straight along y from the robot: its range pins y down
      assert sy < sy0 / 2
    end

    test "the covariance stays symmetric positive definite over many updates" do
      ekf = EKF.new({1.0, 1.0, 0.0}, EKF.diagonal(2.0, 2.0, 1.0))

      ekf =
        Enum.reduce(1..300, ekf, fn i, ekf ->
          {id, at} = Enum.at(@beacons, rem(i, 5))
          {r, b} = EKF.measure({1.0, 1.0, 0.0}, at)

          {_, ekf, _} =
            EKF.update_beacon(ekf, %{id: id, range: r, bearing: b}, at, {0.001, 0.001})

          ekf
        end)

      [[a, b, c], [d, e, f], [g, h, i]] = EKF.covariance_list(ekf)
      assert {b, c, f} == {d, g, h}
      assert a > 0 and a * e - b * d > 0
      assert a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0
    end
  end

  describe "locate/5" do
    test "fixes the pose from detections alone, from a poor guess" do
      truth = {3.0, 5.0, -0.8}
      rng = :rand.seed_s(:exsss, 9)

      {detections, _} =
        Enum.map_reduce(@beacons, rng, fn {id, at}, rng ->
          {r, b} = EKF.measure(truth, at)
          {nr, rng} = :rand.normal_s(rng)
          {nb, rng} = :rand.normal_s(rng)
          {%{id: id, range: r + 0.02 * nr, bearing: b + 0.02 * nb}, rng}
        end)

      assert {:ok, fix, chi2} = EKF.locate(detections, @beacons, @sensor, {5.0, 3.0, 0.0})
      {x, y, th} = fix.pose
      {sx, sy, sth} = EKF.sigmas(fix)
      assert abs(x - 3.0) < 3 * sx and abs(y - 5.0) < 3 * sy and abs(th + 0.8) < 3 * sth
      assert sx < 0.03 and sth < 0.03
      # 10 measurements, 3 unknowns
      assert chi2 < 25.0

      # a detection made up far off shows in the residual
      [first | rest] = detections

      assert {:ok, _, bad} =
               EKF.locate([%{first | range: first.range + 2.0} | rest], @beacons, @sensor, truth)

      assert bad > 1000
    end

    test "needs two known beacons" do
      assert {:error, :too_few} =
               EKF.locate(
                 [%{id: :b1, range: 1.0, bearing: 0.0}, %{id: :zz, range: 2.0, bearing: 1.0}],
                 @beacons,
                 @sensor,
                 {1.0, 1.0, 0.0}
               )
    end
  end

  describe "predict/3" do
    test "grows the covariance with distance and turn" do
      ekf = EKF.new({1.0, 2.0, 0.3}, EKF.diagonal(0.01, 0.01, 0.01))
      moved = EKF.predict(ekf, {1.0, 0.0, 0.5}, @noise)
      [[a0, _, _], [_, e0, _], [_, _, i0]] = EKF.covariance_list(ekf)
      [[a, _, _], [_, e, _], [_, _, i]] = EKF.covariance_list(moved)
      assert a > a0 and e > e0 and i > i0

      # a longer step grows it more
      further = EKF.predict(ekf, {2.0, 0.0, 1.0}, @noise)
      [[a2, _, _], [_, e2, _], [_, _, i2]] = EKF.covariance_list(further)
      assert a2 > a and e2 > e and i2 > i

      # standing still only adds the floor
      still = EKF.predict(ekf, {0.0, 0.0, 0.0}, @noise)
      [[as, _, _], _, [_, _, is]] = EKF.covariance_list(still)
      assert_in_delta as, a0 + 1.0e-6, 1.0e-12
      assert_in_delta is, i0 + 1.0e-6, 1.0e-12
    end

    test "moves the pose by composition" do
      ekf = EKF.new({1.0, 2.0, :math.pi() / 2}, EKF.diagonal(0.1, 0.1, 0.1))
      %EKF{pose: {x, y, th}} = EKF.predict(ekf, {1.0, 0.5, 0.1}, @noise)
      assert_in_delta x, 0.5, 1.0e-9
      assert_in_delta y, 3.0, 1.0e-9
      assert_in_delta th, :math.pi() / 2 + 0.1, 1.0e-9
    end
  end

  test "relative/2 inverts motion/2, whatever the odometry frame" do
    for {pose, delta} <- [
          {{0.0, 0.0, 0.0}, {0.3, 0.0, 0.1}},
          {{5.0, -2.0, 3.0}, {-0.2, 0.1, -0.4}},
          {{-1.0, 4.0, -2.5}, {0.0, 0.0, 1.0}}
        ] do
      {dx, dy, dth} = EKF.relative(pose, EKF.motion(pose, delta))
      {ex, ey, eth} = delta
      assert_in_delta dx, ex, 1.0e-9
      assert_in_delta dy, ey, 1.0e-9
      assert_in_delta dth, eth, 1.0e-9
    end
  end

  describe "Jacobians against finite differences" do
    @h 1.0e-6

    defp numeric(f, pose, n_out) do
      for i <- 0..(n_out - 1) do
        for j <- 0..2 do
          plus = put_elem(pose, j, elem(pose, j) + @h)
          minus = put_elem(pose, j, elem(pose, j) - @h)
          d = elem(f.(plus), i) - elem(f.(minus), i)
          # bearings and headings: the difference of two angles
          d = if i == n_out - 1, do: normalize_angle(d), else: d
          d / (2 * @h)
        end
      end
    end

    defp rows(m), do: m |> Tuple.to_list() |> Enum.map(&Tuple.to_list/1)

    test "measurement Jacobian, with and without a sensor offset" do
      for pose <- [{1.0, 2.0, 0.3}, {-3.0, 0.5, 2.9}, {4.0, 4.0, -1.7}],
          beacon <- [{6.0, -1.0}, {-2.0, 5.0}],
          sensor <- [{0.0, 0.0, 0.0}, {0.2, -0.1, 0.4}] do
        analytic = rows(EKF.measurement_jacobian(pose, beacon, sensor))
        numeric = numeric(&EKF.measure(&1, beacon, sensor), pose, 2)

        for {ra, rn} <- Enum.zip(analytic, numeric),
            {a, n} <- Enum.zip(ra, rn),
            do: assert_in_delta(a, n, 1.0e-5)
      end
    end

    test "motion Jacobians" do
      pose = {1.0, -2.0, 0.7}
      delta = {0.4, -0.1, 0.3}
      {f, g} = EKF.motion_jacobians(pose, delta)

      nf = numeric(&EKF.motion(&1, delta), pose, 3)
      ng = numeric(&EKF.motion(pose, &1), delta, 3)

      for {a, n} <- Enum.zip(List.flatten(rows(f)), List.flatten(nf)),
          do: assert_in_delta(a, n, 1.0e-5)

      for {a, n} <- Enum.zip(List.flatten(rows(g)), List.flatten(ng)),
          do: assert_in_delta(a, n, 1.0e-5)
    end
  end
end
