defmodule ThinkingCap.Navigation.OdometryCalibrationTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.OdometryCalibration, as: C

  # corrections from an odometry that turns 3 % too far and curves
  # 0.012 rad a metre, with noise
  defp corrections(n, seed) do
    rng = :rand.seed_s(:exsss, {seed, 2, 3})

    {samples, _} =
      Enum.map_reduce(1..n, rng, fn _, rng ->
        {u1, rng} = :rand.uniform_s(rng)
        {u2, rng} = :rand.uniform_s(rng)
        {g, rng} = :rand.normal_s(rng)
        turn = (u1 - 0.5) * 0.4
        distance = u2 * 0.1
        {{turn, distance, -0.03 * turn + 0.012 * distance + 0.002 * g}, rng}
      end)

    samples
  end

  test "learns the turn scale and the turn per metre from the corrections" do
    c =
      Enum.reduce(corrections(3000, 1), C.new(), fn {r, d, delta}, c ->
        C.learn(c, r, d, delta)
      end)

    assert_in_delta c.a, -0.03, 0.005
    assert_in_delta c.b, 0.012, 0.004

    # and takes them out of a move
    {dx, dy, dth} = C.apply_to(c, {1.0, 0.0, 1.0})
    assert {dx, dy} == {1.0, 0.0}
    assert_in_delta dth, 1.0 - 0.03 + 0.012, 0.01
  end

  test "changes nothing before it has seen enough, and stays within its bounds" do
    c = C.new()
    assert C.apply_to(c, {0.1, 0.0, 0.2}) == {0.1, 0.0, 0.2}

    # a correction after a small turn is little evidence: it moves it little
    c1 = C.learn(c, 0.02, 0.0, 0.02)
    assert abs(c1.a) < 0.005

    # corrections that make no sense as odometry errors are bounded
    c2 = Enum.reduce(1..500, c, fn _, c -> C.learn(c, 0.2, 0.1, 0.5) end)
    assert abs(c2.a) <= 0.05 and abs(c2.b) <= 0.05
  end

  test "backwards is a negative distance" do
    assert C.signed_distance(-0.3, 0.4) == -0.5
    assert C.signed_distance(0.3, 0.4) == 0.5
  end
end
