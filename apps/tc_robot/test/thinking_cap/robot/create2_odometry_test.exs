defmodule ThinkingCap.Robot.Create2OdometryTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.Create2.Odometry

  @r 0.036
  @b 0.235
  @per_meter 508.8 / (2 * :math.pi() * @r)

  defp counts(meters), do: round(meters * @per_meter)

  test "the first counts are the reference; straight ahead adds up" do
    odo = Odometry.new(@r, @b) |> Odometry.update(1000, 2000, 0.0)
    assert odo.pose == {0.0, 0.0, 0.0}

    odo =
      Enum.reduce(1..100, odo, fn i, odo ->
        Odometry.update(odo, 1000 + counts(i * 0.003), 2000 + counts(i * 0.003), i * 0.015)
      end)

    {x, y, theta} = odo.pose
    assert_in_delta x, 0.3, 0.001
    assert_in_delta y, 0.0, 1.0e-9
    assert_in_delta theta, 0.0, 1.0e-9
    # 3 mm a 15 ms step: 0.2 m/s, up to a count's rounding
    assert_in_delta odo.v, 0.2, 0.02
  end

  test "the counters wrap at 65536, both ways" do
    assert Odometry.wrap(5 - 65_530) == 11
    assert Odometry.wrap(65_530 - 5) == -11
    assert Odometry.wrap(100) == 100

    odo = Odometry.new(@r, @b) |> Odometry.update(65_500, 36, 0.0)
    # left forward across the wrap, right backward across it: a turn clockwise
    odo = Odometry.update(odo, 64, 65_472, 1.0)
    {_, _, theta} = odo.pose
    d = 100 / @per_meter
    assert_in_delta theta, -2 * d / @b, 1.0e-9
    assert odo.w < 0
  end

  test "turning in place a quarter turn" do
    quarter = counts(:math.pi() / 2 * @b / 2)
    odo = Odometry.new(@r, @b) |> Odometry.update(0, 0, 0.0)
    odo = Odometry.update(odo, Integer.mod(-quarter, 65_536), quarter, 1.0)
    {x, y, theta} = odo.pose
    assert_in_delta theta, :math.pi() / 2, 0.01
    assert_in_delta x, 0.0, 1.0e-9
    assert_in_delta y, 0.0, 1.0e-9
  end

  test "rebase keeps the pose and takes the next counts as the reference" do
    odo = Odometry.new(@r, @b) |> Odometry.update(0, 0, 0.0) |> Odometry.update(500, 500, 0.015)
    {x, _, _} = odo.pose
    odo = odo |> Odometry.rebase() |> Odometry.update(30_000, 12, 1.0)
    assert {^x, _, _} = odo.pose
    assert %{left_counts: 30_000, right_counts: 12, stamp: 1.0} = Odometry.reading(odo)
  end

  test "a step no wheel could make is not integrated; it becomes the reference" do
    odo = Odometry.new(@r, @b) |> Odometry.update(1000, 1000, 0.0)
    # 30 000 counts (13 m) in 15 ms
    odo = Odometry.update(odo, 31_000, 1000, 0.015)
    assert odo.pose == {0.0, 0.0, 0.0}
    assert odo.jumps == 1
    odo = Odometry.update(odo, 31_010, 1010, 0.030)
    {x, _, _} = odo.pose
    assert_in_delta x, 10 / @per_meter, 1.0e-9
    # after a second without counts (frames lost), a second's worth is fine
    odo = Odometry.update(odo, 31_010 + 1000, 1010 + 1000, 1.030)
    assert odo.jumps == 1
  end

  test "a step over frames lost is judged on their periods, though read at one stamp" do
    # ten frames lost at 0.37 m/s: 127 counts (56 mm), arriving in the same
    # read of the line as the frame before them
    odo = Odometry.new(@r, @b) |> Odometry.update(1000, 1000, 2.0)
    lost = Odometry.update(odo, 1127, 1127, 2.0, 11)
    assert lost.jumps == 0
    {x, _, _} = lost.pose
    assert_in_delta x, 127 / @per_meter, 1.0e-9

    # the same step taken as one frame's is no wheel's
    assert Odometry.update(odo, 1127, 1127, 2.0).jumps == 1
  end
end
