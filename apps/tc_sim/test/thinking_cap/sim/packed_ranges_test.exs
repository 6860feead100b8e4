defmodule ThinkingCap.Sim.PackedRangesTest do
  # Controllers that take ranges as binaries (Sim.Controller.packed_ranges?/0)
  # read what the others read as lists.
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.{Raycast, Wander}
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir

  defmodule Packed do
    # keeps the readings of every step, as ThinkingCap.Testing.Cruise does
    @behaviour ThinkingCap.Sim.Controller
    @impl true
    def init(_args, _info), do: []
    @impl true
    def control(readings, seen), do: {{:velocity, 0.3, 0.2}, [readings | seen]}
    @impl true
    def packed_ranges?, do: true
  end

  defmodule Lists do
    @behaviour ThinkingCap.Sim.Controller
    @impl true
    def init(_args, _info), do: []
    @impl true
    def control(readings, seen), do: {{:velocity, 0.3, 0.2}, [readings | seen]}
  end

  @sensors [
    [name: :laser, type: :laser, range: {0.05, 8.0}, fov: 3.0, beams: 61, rate: 10],
    [
      name: :sonar,
      type: :sonar,
      count: 8,
      ring_radius: 0.2,
      range: {0.05, 5.0},
      fov: 0.26,
      rays: 3,
      max_reflections: 1,
      rate: 10,
      noise: [stddev: 0.01],
      faults: [[type: :stuck, probability: 0.5, after: 0.3]]
    ]
  ]

  # the readings each controller saw, oldest first
  defp run(dir, controller, opts \\ []) do
    {:ok, sim} =
      Sim.start_link(
        [
          world: T.world!(dir, walls: T.box(10, 10)),
          mode: :fast,
          running: false,
          seed: 3,
          step: 0.1
        ] ++
          opts
      )

    robot = T.robot!(dir, sensors: @sensors)
    :ok = Sim.add_robot(sim, :r, description: robot, at: {5, 5, 0.4}, controller: controller)
    :ok = Sim.step(sim, 10)
    {:ok, seen} = Sim.controller_state(sim, :r)
    GenServer.stop(sim)
    Enum.reverse(seen)
  end

  defp unpack(ranges), do: for(<<r::float-little-64 <- ranges>>, do: r)

  test "packed ranges hold the readings a list holds, faults included", %{tmp_dir: dir} do
    packed = run(dir, {Packed, []})
    lists = run(dir, {Lists, []})
    assert length(packed) == 10

    for {p, l} <- Enum.zip(packed, lists), sensor <- [:laser, :sonar] do
      assert is_binary(p[sensor].ranges)
      assert is_list(l[sensor].ranges)
      assert unpack(p[sensor].ranges) == l[sensor].ranges
      assert Map.delete(p[sensor], :ranges) == Map.delete(l[sensor], :ranges)
    end

    # the stuck transducers kept their reading
    sonar = Enum.map(packed, &unpack(&1.sonar.ranges))

    assert Enum.any?(0..7, fn i ->
             sonar |> Enum.drop(4) |> Enum.map(&Enum.at(&1, i)) |> Enum.uniq() |> length() == 1
           end)
  end

  test "ranges published on the blackboard stay lists", %{tmp_dir: dir} do
    [first | _] = run(dir, {Packed, []}, publish: true)
    assert is_list(first.laser.ranges)
  end

  test "ranges_min is the least of a slice of a packed scan" do
    values = [3.0, 1.5, 2.0, 0.7, 9.0, 0.9]
    bin = for r <- values, into: <<>>, do: <<r::float-little-64>>
    assert Raycast.ranges_min(bin, 0, 6) == 0.7
    assert Raycast.ranges_min(bin, 1, 2) == 1.5
    assert Raycast.ranges_min(bin, 4, 2) == 0.9
    assert Raycast.ranges_min(bin, 5, 1) == 0.9
    assert_raise ArgumentError, fn -> Raycast.ranges_min(bin, 5, 2) end
    assert_raise ArgumentError, fn -> Raycast.ranges_min(bin, 0, 0) end
    assert_raise ArgumentError, fn -> Raycast.ranges_min(bin, 6, 1) end
  end

  test "Wander steers the same on packed and listed ranges", %{tmp_dir: dir} do
    robot = T.robot!(dir, sensors: @sensors)

    for laser? <- [true, false], seed <- 1..20 do
      d = if laser?, do: robot, else: %{robot | sensors: tl(robot.sensors)}
      sensor = if laser?, do: :laser, else: :sonar
      state = Wander.init([seed: seed], %{robot: :r, description: d})
      rng = :rand.seed_s(:exsss, {seed, 1, 2})
      n = if laser?, do: 61, else: 8
      {ranges, _} = Enum.map_reduce(1..n, rng, fn _, rng -> :rand.uniform_s(rng) end)
      ranges = Enum.map(ranges, &(&1 * 3))

      payload =
        if laser?,
          do: %{angle_min: -1.5, angle_max: 1.5, angle_increment: 0.05},
          else: %{headings: Enum.map(0..7, &(&1 * :math.pi() / 4))}

      listed = Map.put(payload, :ranges, ranges)
      packed = Map.put(payload, :ranges, for(r <- ranges, into: <<>>, do: <<r::float-little-64>>))

      assert Wander.control(%{sensor => packed}, state) ==
               Wander.control(%{sensor => listed}, state)
    end
  end
end
