defmodule ThinkingCap.Test.DriftingCircle do
  @moduledoc false
  # A robot driven round a circle of 2 m about {4, 3} (the centre of an
  # 8 x 6 m room), heading along it, 36 steps a turn, and what a drifting
  # estimate says of it: each step turning `drift` rad too far. For the
  # loop-closure tests.

  alias ThinkingCap.Navigation.EKF
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @doc "The true poses and the drifting estimates of `steps + 1` nodes."
  def poses(steps, drift \\ 0.01) do
    truth =
      for k <- 0..steps do
        a = k * 2 * :math.pi() / 36
        {4.0 + 2.0 * :math.cos(a), 3.0 + 2.0 * :math.sin(a), normalize_angle(a + :math.pi() / 2)}
      end

    estimates =
      truth
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.map(fn [a, b] -> EKF.relative(a, b) end)
      |> Enum.scan(hd(truth), fn {dx, dy, dth}, pose ->
        EKF.motion(pose, {dx, dy, dth + drift})
      end)

    {truth, [hd(truth) | estimates]}
  end

  @doc """
  Each true pose with its estimate (drifting `drift` a step) handed to `fun.(true_pose, estimate,
  acc)`, which returns `{acc, :none}` or `{acc, {:closed, from, to}}`: a
  closed loop moves the map's frame under the robot, and the later
  estimates are carried along (as `ThinkingCap.Navigation.MCL` does).
  Returns the accumulator and the number of loops closed.
  """
  def drive(steps, acc, fun, drift \\ 0.01) do
    {truth, estimates} = poses(steps, drift)

    {acc, closed, _moves} =
      Enum.zip(truth, estimates)
      |> Enum.reduce({acc, 0, []}, fn {true_pose, estimate}, {acc, closed, moves} ->
        estimate =
          Enum.reduce(moves, estimate, fn {from, to}, p ->
            EKF.motion(to, EKF.relative(from, p))
          end)

        case fun.(true_pose, estimate, acc) do
          {acc, :none} -> {acc, closed, moves}
          {acc, {:closed, from, to}} -> {acc, closed + 1, moves ++ [{from, to}]}
        end
      end)

    {acc, closed}
  end
end
