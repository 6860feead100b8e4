defmodule ThinkingCap.Sim.FaultsTest do
  # Sensor noise and fault models, checked by their statistics.
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir

  # a robot at the centre of a 10 m box: every laser beam has an echo
  defp scans(dir, laser_opts, steps, opts \\ []) do
    laser =
      Keyword.merge(
        [name: :laser, type: :laser, range: {0.05, 8.0}, fov: 3.0, beams: 61, rate: 100],
        laser_opts
      )

    {:ok, sim} =
      Sim.start_link(
        world: T.world!(dir, walls: T.box(10, 10)),
        mode: :fast,
        running: false,
        seed: Keyword.get(opts, :seed, 1)
      )

    robot = T.robot!(dir, sensors: [laser])
    :ok = Sim.add_robot(sim, :r, description: robot, at: {5, 5, 0}, owner: self())
    if cmd = opts[:command], do: Sim.command(sim, :r, cmd)
    :ok = Sim.step(sim, steps)

    scans = drain([])
    GenServer.stop(sim)
    scans
  end

  # the laser scans delivered so far, oldest first (steps without a
  # reading deliver nothing)
  defp drain(acc) do
    receive do
      {:tc_sim, :readings, :r, readings} ->
        case Map.new(readings) do
          %{laser: scan} -> drain([scan | acc])
          _ -> drain(acc)
        end
    after
      0 -> Enum.reverse(acc)
    end
  end

  # the noise-free scan
  defp truth(dir), do: hd(scans(dir, [], 1)).ranges

  defp mean(xs), do: Enum.sum(xs) / length(xs)

  defp std(xs) do
    m = mean(xs)
    :math.sqrt(Enum.sum(Enum.map(xs, &((&1 - m) ** 2))) / (length(xs) - 1))
  end

  test "Gaussian noise has the configured spread, plus a part growing with range", %{
    tmp_dir: dir
  } do
    truth = truth(dir)
    scans = scans(dir, [noise: [stddev: 0.05, proportional: 0.01]], 300)
    errors = for s <- scans, {r, t} <- Enum.zip(s.ranges, truth), do: {r - t, t}
    # normalised by the expected sigma of each reading
    z = for {e, t} <- errors, do: e / (0.05 + 0.01 * t)
    assert_in_delta mean(z), 0.0, 0.03
    assert_in_delta std(z), 1.0, 0.03
  end

  test "dropouts read max range with their probability", %{tmp_dir: dir} do
    scans = scans(dir, [faults: [[type: :dropout, probability: 0.2]]], 200)
    readings = Enum.flat_map(scans, & &1.ranges)
    share = Enum.count(readings, &(&1 == 8.0)) / length(readings)
    # 12,200 readings: sigma of the share is 0.0036
    assert_in_delta share, 0.2, 0.015
  end

  test "spikes replace readings with random ones with their probability", %{tmp_dir: dir} do
    truth = truth(dir)
    scans = scans(dir, [faults: [[type: :spikes, probability: 0.1]]], 200)
    pairs = for s <- scans, {r, t} <- Enum.zip(s.ranges, truth), do: {r, t}
    spiked = for {r, t} <- pairs, abs(r - t) > 1.0e-9, do: r
    assert_in_delta length(spiked) / length(pairs), 0.1, 0.012
    # uniform over the range: mean near the middle
    assert_in_delta mean(spiked), (0.05 + 8.0) / 2, 0.3
    assert Enum.all?(spiked, &(&1 >= 0.05 and &1 <= 8.0))
  end

  test "a drifting bias grows with time after its start", %{tmp_dir: dir} do
    truth = truth(dir)
    scans = scans(dir, [faults: [[type: :drift, magnitude: 0.1, after: 0.5]]], 150)

    for s <- scans do
      expected = if s.stamp >= 0.5, do: 0.1 * (s.stamp - 0.5), else: 0.0
      for {r, t} <- Enum.zip(s.ranges, truth), do: assert_in_delta(r, t + expected, 1.0e-9)
    end
  end

  test "a stuck sensor keeps the reading it had when the fault started", %{tmp_dir: dir} do
    # the robot drives towards the east wall: the readings should shrink
    scans =
      scans(dir, [faults: [[type: :stuck, after: 0.2]]], 100, command: {:velocity, 0.5, 0.0})

    {before, stuck} = Enum.split_with(scans, &(&1.stamp < 0.2))
    ahead = fn s -> Enum.at(s.ranges, 30) end
    assert ahead.(List.last(before)) < ahead.(hd(before))
    assert stuck |> Enum.map(& &1.ranges) |> Enum.uniq() |> length() == 1
  end

  test "a dead sensor falls silent; whether it dies follows its probability", %{tmp_dir: dir} do
    scans = scans(dir, [faults: [[type: :dead, after: 0.3]]], 60)
    assert length(scans) == 30
    assert Enum.all?(scans, &(&1.stamp < 0.3))

    dead =
      Enum.count(1..40, fn seed ->
        scans(dir, [faults: [[type: :dead, probability: 0.5]]], 2, seed: seed) == []
      end)

    # binomial(40, 0.5): within 4 sigma
    assert dead in 7..33
  end
end
