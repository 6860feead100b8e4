defmodule ThinkingCap.Robot.KinematicsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.Kinematics
  alias ThinkingCap.Robot.Kinematics.{Ackermann, Differential, Tricycle}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @pi :math.pi()

  defp diff(extra \\ %{}),
    do:
      Kinematics.new(
        Map.merge(%{type: :differential, wheel_radius: 0.05, wheel_separation: 0.4}, extra)
      )

  defp tricycle(extra \\ %{}),
    do: Kinematics.new(Map.merge(%{type: :tricycle, wheelbase: 1.2, max_steering: 1.2}, extra))

  defp ackermann(extra \\ %{}),
    do:
      Kinematics.new(
        Map.merge(%{type: :ackermann, wheelbase: 2.5, track: 1.5, max_steering: 0.6}, extra)
      )

  defp assert_pose({x, y, t}, {ex, ey, et}, eps \\ 1.0e-9) do
    assert_in_delta x, ex, eps
    assert_in_delta y, ey, eps
    # angles compared on the circle
    assert_in_delta normalize_angle(t - et), 0.0, eps
  end

  defp assert_twist({v, w}, {ev, ew}, eps \\ 1.0e-9) do
    assert_in_delta v, ev, eps
    assert_in_delta w, ew, eps
  end

  # integrates a constant twist for `t` seconds in steps of `dt`
  defp drive(pose, twist, t, dt) do
    Enum.reduce(1..round(t / dt), pose, fn _, p -> Kinematics.integrate(p, twist, dt) end)
  end

  describe "new/1" do
    test "builds the model of each drive from the RDF's kinematics map, limits defaulted" do
      assert %Differential{wheel_radius: 0.05, wheel_separation: 0.4, max_speed: 1.0} = diff()
      assert Kinematics.type(diff()) == :differential
      assert %Tricycle{wheelbase: 1.2, max_steering: 1.2, max_turn_rate: 1.5} = tricycle()
      assert Kinematics.type(tricycle()) == :tricycle
      assert %Ackermann{track: 1.5, max_acceleration: 1.0} = ackermann()
      assert Kinematics.type(ackermann()) == :ackermann

      # the RDF's maps carry nil for keys not given
      assert %Differential{max_speed: 0.4, max_turn_rate: 1.5} =
               diff(%{max_speed: 0.4, max_turn_rate: nil, wheelbase: nil})

      assert Kinematics.limits(ackermann(%{max_speed: 3})) == %{
               max_speed: 3.0,
               max_turn_rate: 1.5,
               max_acceleration: 1.0,
               max_steering: 0.6
             }
    end

    test "missing geometry is an ArgumentError naming the parameter" do
      assert_raise ArgumentError, ~r/differential drive needs wheel_separation: .* got nil/, fn ->
        Kinematics.new(%{type: :differential, wheel_radius: 0.1})
      end

      assert_raise ArgumentError, ~r/ackermann drive needs track:/, fn ->
        Kinematics.new(type: :ackermann, wheelbase: 2, max_steering: 0.5)
      end

      assert_raise ArgumentError, ~r/max_steering: below π\/2/, fn ->
        ackermann(%{max_steering: 1.6})
      end

      assert_raise ArgumentError, ~r/got :hover/, fn -> Kinematics.new(%{type: :hover}) end
    end
  end

  describe "integrate/3" do
    test "a straight line" do
      pose = drive({1.0, 2.0, @pi / 4}, {0.5, 0.0}, 2.0, 0.1)
      d = 1.0 / :math.sqrt(2)
      assert_pose(pose, {1.0 + d, 2.0 + d, @pi / 4})
    end

    test "turning in place: (0, 0, ωt)" do
      assert_pose(drive({0.0, 0.0, 0.0}, {0.0, 0.7}, 2.0, 0.01), {0.0, 0.0, 1.4})
      assert_pose(drive({0.0, 0.0, 0.0}, {0.0, -0.7}, 2.0, 0.5), {0.0, 0.0, -1.4})
    end

    test "an arc of radius v/ω: quarter and half turns, either way, forwards and back" do
      {v, w} = {0.5, 0.25}
      r = v / w
      quarter = @pi / 2 / w

      assert_pose(Kinematics.integrate({0.0, 0.0, 0.0}, {v, w}, quarter), {r, r, @pi / 2})
      # the same arc in 100 steps: the integration is exact, not Euler
      assert_pose(drive({0.0, 0.0, 0.0}, {v, w}, quarter, quarter / 100), {r, r, @pi / 2})

      # half a turn ends at θ = π, normalised to (−π, π]
      {_, _, theta} = half = Kinematics.integrate({0.0, 0.0, 0.0}, {v, w}, 2 * quarter)
      assert_pose(half, {0.0, 2 * r, @pi})
      assert theta > 0

      # turning right (ω < 0): centre at (0, −r)
      assert_pose(Kinematics.integrate({0.0, 0.0, 0.0}, {v, -w}, quarter), {r, -r, -@pi / 2})
      # reversing while turning left: backwards along the circle about (0, −r)
      assert_pose(Kinematics.integrate({0.0, 0.0, 0.0}, {-v, w}, quarter), {-r, -r, @pi / 2})

      # from a non-zero pose: rotate the quarter turn by the start heading
      assert_pose(
        Kinematics.integrate({1.0, 1.0, @pi / 2}, {v, w}, quarter),
        {1.0 - r, 1.0 + r, @pi}
      )
    end

    test "a tiny ω is a straight line, without loss of precision" do
      {x, y, t} = Kinematics.integrate({0.0, 0.0, 0.0}, {1.0, 1.0e-12}, 1.0)
      assert_in_delta x, 1.0, 1.0e-12
      assert_in_delta y, 0.5e-12, 1.0e-15
      assert_in_delta t, 1.0e-12, 1.0e-18
    end
  end

  describe "differential" do
    test "forward: equal wheels go straight, opposite wheels turn in place" do
      m = diff()
      assert_twist(Kinematics.forward(m, {:wheels, 10.0, 10.0}), {0.5, 0.0})
      # right wheel forward, left back: counter-clockwise
      assert_twist(Kinematics.forward(m, {:wheels, -4.0, 4.0}), {0.0, 2 * 0.05 * 4.0 / 0.4})
    end

    test "inverse is wheel_speeds, and forward ∘ inverse is the identity" do
      m = diff()
      assert {:wheels, l, r} = Kinematics.inverse(m, {0.3, 1.0})
      assert {:wheels, ^l, ^r} = Differential.wheel_speeds(m, {0.3, 1.0})
      assert_in_delta l, (0.3 - 0.2) / 0.05, 1.0e-12
      assert_in_delta r, (0.3 + 0.2) / 0.05, 1.0e-12

      for v <- [-1.0, -0.2, 0.0, 0.4, 1.0], w <- [-2.0, 0.0, 0.3, 1.5] do
        assert_twist(Kinematics.forward(m, Kinematics.inverse(m, {v, w})), {v, w}, 1.0e-12)
      end
    end
  end

  describe "tricycle" do
    test "forward: v = u cos δ, ω = u sin δ / L, turning radius L / tan δ" do
      m = tricycle()
      {v, w} = Kinematics.forward(m, {:steer, 1.0, 0.4})
      assert_in_delta v, :math.cos(0.4), 1.0e-12
      assert_in_delta w, :math.sin(0.4) / 1.2, 1.0e-12
      radius = 1.2 / :math.tan(0.4)
      assert_in_delta v / w, radius, 1.0e-12

      # a quarter turn about the centre (0, R) on the rear axle line
      pose = Kinematics.integrate({0.0, 0.0, 0.0}, {v, w}, @pi / 2 / w)
      assert_pose(pose, {radius, radius, @pi / 2})
    end

    test "forward ∘ inverse is the identity within the steering limit, reversing too" do
      m = tricycle()

      for v <- [-1.0, -0.3, 0.3, 1.0], w <- [-0.5, 0.0, 0.4] do
        assert {:steer, u, delta} = Kinematics.inverse(m, {v, w})
        assert abs(delta) <= 1.2
        # reversing: the wheel rolls backwards, it is not turned round
        assert u * v > 0
        assert_twist(Kinematics.forward(m, {:steer, u, delta}), {v, w}, 1.0e-12)
      end
    end

    test "inverse clamps the steering, keeping v; at v = 0 only a ±π/2 wheel turns on the spot" do
      m = tricycle()
      # ω L / v = 3 needs atan 3 = 1.25 rad > 1.2
      assert {:steer, u, 1.2} = Kinematics.inverse(m, {1.0, 2.5})
      {v, w} = Kinematics.forward(m, {:steer, u, 1.2})
      assert_in_delta v, 1.0, 1.0e-12
      assert_in_delta w, :math.tan(1.2) / 1.2, 1.0e-12

      assert {:steer, +0.0, -1.2} = Kinematics.inverse(m, {0.0, -1.0})

      spin = tricycle(%{max_steering: @pi / 2})
      assert {:steer, u, delta} = Kinematics.inverse(spin, {0.0, -1.0})
      assert_in_delta delta, -@pi / 2, 1.0e-12
      assert_twist(Kinematics.forward(spin, {:steer, u, delta}), {0.0, -1.0}, 1.0e-12)
    end
  end

  describe "Ackermann" do
    test "forward: v = u, ω = u tan δ / L; inverse undoes it" do
      m = ackermann()
      assert_twist(Kinematics.forward(m, {:steer, 2.0, 0.3}), {2.0, 2.0 * :math.tan(0.3) / 2.5})

      for v <- [-2.0, -1.0, 1.0, 3.0], w <- [-0.2, 0.0, 0.1] do
        assert {:steer, u, delta} = Kinematics.inverse(m, {v, w})
        assert u == v
        assert_twist(Kinematics.forward(m, {:steer, u, delta}), {v, w}, 1.0e-12)
      end
    end

    test "inverse clamps the steering to max_steering, and ω at v = 0" do
      m = ackermann()
      assert Kinematics.inverse(m, {1.0, 5.0}) == {:steer, 1.0, 0.6}
      assert Kinematics.inverse(m, {-1.0, 5.0}) == {:steer, -1.0, -0.6}
      assert Kinematics.inverse(m, {0.0, 0.5}) == {:steer, 0.0, 0.6}
      assert Kinematics.inverse(m, {0.0, -0.5}) == {:steer, 0.0, -0.6}
      assert Kinematics.inverse(m, {0.0, 0.0}) == {:steer, 0.0, 0.0}
    end

    test "turning radius L / tan δ, signed, infinite going straight" do
      m = ackermann()
      assert_in_delta Ackermann.turning_radius(m, 0.3), 2.5 / :math.tan(0.3), 1.0e-12
      assert_in_delta Ackermann.turning_radius(m, -0.3), -2.5 / :math.tan(0.3), 1.0e-12
      assert Ackermann.turning_radius(m, 0.0) == :infinity
      assert Ackermann.turning_radius(m, 0) == :infinity

      # the radius the forward model drives
      {v, w} = Kinematics.forward(m, {:steer, 1.0, 0.3})
      assert_in_delta v / w, Ackermann.turning_radius(m, 0.3), 1.0e-12
    end

    test "inner and outer wheel angles: tan relations, axes meeting at the turning centre" do
      m = ackermann()
      {l, t} = {2.5, 1.5}

      for delta <- [0.05, 0.3, 0.6, -0.2, -0.6] do
        {left, right} = Ackermann.wheel_angles(m, delta)
        r = Ackermann.turning_radius(m, delta)
        assert_in_delta :math.tan(left), l / (r - t / 2), 1.0e-9
        assert_in_delta :math.tan(right), l / (r + t / 2), 1.0e-9

        # each wheel at (L, ±t/2); its axle line (−sin α, cos α) meets the
        # rear axle line x = 0 at y = ±t/2 + L / tan α: the centre (0, R)
        assert_in_delta t / 2 + l / :math.tan(left), r, 1.0e-9
        assert_in_delta -t / 2 + l / :math.tan(right), r, 1.0e-9

        # the inner wheel (on the side of the turn) steers more; the bicycle angle is between
        {inner, outer} = if delta > 0, do: {left, right}, else: {right, left}
        assert abs(inner) > abs(delta) and abs(delta) > abs(outer)
        assert inner * delta > 0 and outer * delta > 0
      end

      assert Ackermann.wheel_angles(m, 0.0) == {0.0, 0.0}
      {l1, r1} = Ackermann.wheel_angles(m, 0.4)
      {l2, r2} = Ackermann.wheel_angles(m, -0.4)
      assert_in_delta l1, -r2, 1.0e-12
      assert_in_delta r1, -l2, 1.0e-12
    end
  end

  describe "limit/4" do
    test "speed and turn rate are clamped" do
      m = diff(%{max_speed: 0.5, max_turn_rate: 1.0, max_acceleration: 100.0})
      assert Kinematics.limit(m, {2.0, -3.0}, {0.5, -1.0}, 0.1) == {0.5, -1.0}
      assert Kinematics.limit(m, {-0.7, 0.4}, {-0.5, 0.4}, 0.1) == {-0.5, 0.4}
      assert Kinematics.limit(m, {0.2, 0.3}, {0.2, 0.3}, 0.1) == {0.2, 0.3}
    end

    test "linear acceleration, and angular acceleration = max_acceleration · max_turn_rate / max_speed" do
      m = diff(%{max_speed: 1.0, max_turn_rate: 2.0, max_acceleration: 0.5})
      {v, w} = Kinematics.limit(m, {1.0, 2.0}, {0.0, 0.0}, 0.1)
      assert_in_delta v, 0.05, 1.0e-12
      # α_max = 0.5 · 2 / 1 = 1 rad/s²
      assert_in_delta w, 0.1, 1.0e-12

      # braking is limited too
      {v, w} = Kinematics.limit(m, {0.0, 0.0}, {0.8, -1.0}, 0.2)
      assert_in_delta v, 0.7, 1.0e-12
      assert_in_delta w, -0.8, 1.0e-12

      # from rest, full speed and full turn rate take the same time
      final =
        Enum.reduce(1..100, {0.0, 0.0}, fn _, prev ->
          Kinematics.limit(m, {1.0, 2.0}, prev, 0.02)
        end)

      assert_twist(final, {1.0, 2.0}, 1.0e-9)

      halfway =
        Enum.reduce(1..50, {0.0, 0.0}, fn _, prev ->
          Kinematics.limit(m, {1.0, 2.0}, prev, 0.02)
        end)

      assert_twist(halfway, {0.5, 1.0}, 1.0e-9)
    end

    test "car-like drives: |ω| ≤ |v| tan(max_steering) / L, none at v = 0" do
      m = ackermann(%{max_speed: 5.0, max_turn_rate: 3.0, max_acceleration: 100.0})
      {v, w} = Kinematics.limit(m, {1.0, 2.0}, {1.0, 0.5}, 1.0)
      assert v == 1.0
      assert_in_delta w, :math.tan(0.6) / 2.5, 1.0e-12
      {_, w} = Kinematics.limit(m, {-2.0, -2.0}, {-2.0, 0.0}, 1.0)
      assert_in_delta w, -2.0 * :math.tan(0.6) / 2.5, 1.0e-12
      assert Kinematics.limit(m, {0.0, 1.0}, {0.0, 0.0}, 1.0) == {0.0, 0.0}

      # the limit uses the speed reachable in this step
      slow = ackermann(%{max_turn_rate: 3.0, max_acceleration: 0.5})
      {v, w} = Kinematics.limit(slow, {1.0, 1.0}, {0.0, 0.0}, 0.1)
      assert_in_delta v, 0.05, 1.0e-12
      assert_in_delta w, 0.05 * :math.tan(0.6) / 2.5, 1.0e-12

      # the limited twist is one the drive can steer: inverse does not clamp it
      {:steer, _, delta} = Kinematics.inverse(m, Kinematics.limit(m, {1.0, 2.0}, {1.0, 0.5}, 1.0))
      assert_in_delta delta, 0.6, 1.0e-12

      t = tricycle(%{max_steering: 0.5, max_acceleration: 100.0})
      {_, w} = Kinematics.limit(t, {0.8, 1.5}, {0.8, 1.5}, 1.0)
      assert_in_delta w, 0.8 * :math.tan(0.5) / 1.2, 1.0e-12
      # a tricycle steering ±π/2 turns on the spot
      assert Kinematics.limit(tricycle(%{max_steering: 1.6}), {0.0, 1.0}, {0.0, 1.0}, 0.1) ==
               {0.0, 1.0}

      # a differential drive has no curvature limit
      assert Kinematics.limit(diff(), {0.0, 1.0}, {0.0, 1.0}, 0.1) == {0.0, 1.0}
    end
  end
end
