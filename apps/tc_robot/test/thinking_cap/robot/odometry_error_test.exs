defmodule ThinkingCap.Robot.OdometryErrorTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.{Kinematics, OdometryError}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @diff %{type: :differential, wheel_radius: 0.05, wheel_separation: 0.4}

  defp diff, do: Kinematics.new(@diff)

  # drives `twist` for `steps` steps of `dt`; the true and odometry poses
  defp run(err, twist, steps, dt) do
    start = {0.0, 0.0, 0.0}

    Enum.reduce(1..steps, {start, start, err}, fn _, {truth, odom, err} ->
      {t, o, err} = OdometryError.step(err, twist, dt)
      {Kinematics.integrate(truth, t, dt), Kinematics.integrate(odom, o, dt), err}
    end)
  end

  defp assert_pose({x, y, t}, {ex, ey, et}, eps) do
    assert_in_delta x, ex, eps
    assert_in_delta y, ey, eps
    assert_in_delta normalize_angle(t - et), 0.0, eps
  end

  defp std(xs) do
    n = length(xs)
    mean = Enum.sum(xs) / n
    {mean, :math.sqrt(Enum.sum(Enum.map(xs, &((&1 - mean) * (&1 - mean)))) / (n - 1))}
  end

  test "without error, the true and odometry twists are the commanded one, for every drive" do
    models = [
      diff(),
      Kinematics.new(type: :tricycle, wheelbase: 1.2, max_steering: 1.0),
      Kinematics.new(type: :ackermann, wheelbase: 2.5, track: 1.5, max_steering: 0.6)
    ]

    for model <- models, twist <- [{0.5, 0.0}, {0.8, 0.2}, {-0.4, -0.1}] do
      # the RDF's defaults, given or not
      for params <- [%{}, %{wheel_diameter_ratio: 1.0, wheelbase_ratio: 1.0, slip: 0.0}] do
        err = OdometryError.new(model, params, 1)
        {truth, odom, _} = OdometryError.step(err, twist, 0.05)
        {v, w} = twist
        assert_in_delta elem(truth, 0), v, 1.0e-12
        assert_in_delta elem(truth, 1), w, 1.0e-12
        assert_in_delta elem(odom, 0), v, 1.0e-12
        assert_in_delta elem(odom, 1), w, 1.0e-12
      end
    end
  end

  test "unequal wheel diameters curve a commanded straight line: κ = 2(E_d − 1) / ((E_d + 1) b)" do
    e_d = 1.01
    err = OdometryError.new(diff(), %{wheel_diameter_ratio: e_d}, 7)
    # 5 m at 0.5 m/s
    {truth, odom, _} = run(err, {0.5, 0.0}, 200, 0.05)

    # the odometry believes it went straight
    assert_pose(odom, {5.0, 0.0, 0.0}, 1.0e-9)

    # the bigger right wheel turns the robot left, along an arc of length 5 m
    kappa = 2 * (e_d - 1) / ((e_d + 1) * 0.4)
    theta = 5.0 * kappa
    r = 1 / kappa
    assert_pose(truth, {r * :math.sin(theta), r * (1 - :math.cos(theta)), theta}, 1.0e-9)
    assert elem(truth, 1) > 0.3

    # the mean radius is nominal: turning in place, the distance driven is unchanged
    {t, _o, _} = OdometryError.step(err, {0.0, 1.0}, 0.1)
    {v, _w} = t
    # (r_r − r_l) / 2 · ω b / (2 r) = ((E_d − 1) / (E_d + 1)) · ω b / 2
    assert_in_delta v, (e_d - 1) / (e_d + 1) * 1.0 * 0.4 / 2, 1.0e-12
  end

  test "a wider wheelbase turns the robot by the odometry's angle / ratio" do
    err = OdometryError.new(diff(), %{wheelbase_ratio: 1.05}, 3)
    {truth, odom, _} = run(err, {0.0, 1.0}, 100, 0.02)
    assert_pose(odom, {0.0, 0.0, 2.0}, 1.0e-9)
    assert_pose(truth, {0.0, 0.0, 2.0 / 1.05}, 1.0e-9)

    # car-like: the actual wheelbase L; arcs keep their speed, turn less
    car = Kinematics.new(type: :ackermann, wheelbase: 2.5, track: 1.5, max_steering: 0.6)
    err = OdometryError.new(car, [wheelbase_ratio: 0.9], 3)
    {{v, w}, {ov, ow}, _} = OdometryError.step(err, {2.0, 0.3}, 0.1)
    assert_in_delta ov, 2.0, 1.0e-12
    assert_in_delta ow, 0.3, 1.0e-12
    assert_in_delta v, 2.0, 1.0e-12
    assert_in_delta w, 0.3 / 0.9, 1.0e-12

    trike = Kinematics.new(type: :tricycle, wheelbase: 1.2, max_steering: 1.0)
    err = OdometryError.new(trike, %{wheelbase_ratio: 1.2}, 3)
    {{v, w}, {ov, ow}, _} = OdometryError.step(err, {0.5, 0.2}, 0.1)
    assert_in_delta ov, 0.5, 1.0e-12
    assert_in_delta ow, 0.2, 1.0e-12
    assert_in_delta v, 0.5, 1.0e-12
    assert_in_delta w, 0.2 / 1.2, 1.0e-12
  end

  test "the odometry reports what inverse clamped, not what was commanded" do
    car = Kinematics.new(type: :ackermann, wheelbase: 2.5, track: 1.5, max_steering: 0.6)
    err = OdometryError.new(car, %{}, 3)
    {{v, w}, {ov, ow}, _} = OdometryError.step(err, {1.0, 2.0}, 0.1)
    assert {v, ov} == {1.0, 1.0}
    assert_in_delta w, :math.tan(0.6) / 2.5, 1.0e-12
    assert_in_delta ow, w, 1.0e-12
  end

  test "slip: the distance error after 1 m has std. dev. slip, whatever the step" do
    slip = 0.02

    for {steps, dt} <- [{100, 0.02}, {8, 0.25}] do
      errors =
        for seed <- 1..400 do
          err = OdometryError.new(diff(), %{slip: slip}, seed)
          {{x, y, theta}, odom, _} = run(err, {0.5, 0.0}, steps, dt)
          # slip moves along the path, and odometry does not see it
          assert y == 0.0 and theta == 0.0
          assert_pose(odom, {1.0, 0.0, 0.0}, 1.0e-12)
          x - 1.0
        end

      {mean, sd} = std(errors)
      # std. error of the mean 0.001, of the std. dev. about 3.5 %
      assert abs(mean) < 0.004
      assert_in_delta sd, slip, 0.15 * slip
    end
  end

  test "turn slip: the heading error after 1 rad has std. dev. turn_slip" do
    errors =
      for seed <- 1..400 do
        err = OdometryError.new(diff(), %{turn_slip: 0.05}, seed)
        # one radian in place, turning clockwise
        {{x, y, theta}, _odom, _} = run(err, {0.0, -0.5}, 40, 0.05)
        assert {x, y} == {0.0, 0.0}
        theta + 1.0
      end

    {mean, sd} = std(errors)
    assert abs(mean) < 0.01
    assert_in_delta sd, 0.05, 0.15 * 0.05
  end

  test "a seed makes a run deterministic; another seed makes another run" do
    params = %{slip: 0.05, turn_slip: 0.05, wheel_diameter_ratio: 1.003}
    a = run(OdometryError.new(diff(), params, 11), {0.4, 0.3}, 50, 0.02)
    b = run(OdometryError.new(diff(), params, 11), {0.4, 0.3}, 50, 0.02)
    c = run(OdometryError.new(diff(), params, 12), {0.4, 0.3}, 50, 0.02)
    assert elem(a, 0) == elem(b, 0)
    assert elem(a, 0) != elem(c, 0)
    # the odometry does not depend on the seed
    assert elem(a, 1) == elem(c, 1)
    # the process's own :rand state is not used
    Process.delete(:rand_seed)
    _ = run(OdometryError.new(diff(), params, 11), {0.4, 0.3}, 5, 0.02)
    assert Process.get(:rand_seed) == nil
  end
end
