defmodule ThinkingCap.Sim.CrowdTest do
  use ExUnit.Case, async: true
  @moduletag :tmp_dir

  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.{Crowd, World}
  alias ThinkingCap.Testing.Sim, as: T

  test "walkers from a seed: the same seed the same routes, legs clear of walls", %{tmp_dir: dir} do
    # a wall across the middle with a gap at the top
    world = T.world!(dir, walls: T.box(20, 10) ++ [{{10, 0}, {10, 7}}])
    walkers = Crowd.walkers(world, count: 30, seed: 5, reach: 6.0)
    assert walkers == Crowd.walkers(world, count: 30, seed: 5, reach: 6.0)
    assert walkers != Crowd.walkers(world, count: 30, seed: 6, reach: 6.0)
    assert length(walkers) == 30

    for {_id, opts} <- walkers do
      route = opts[:route]
      assert length(route) == 3
      assert opts[:speed] >= 0.6 and opts[:speed] <= 1.2

      for {{ax, ay}, {bx, by}} <- Enum.zip(route, tl(route)) do
        assert :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2) <= 6.0

        # no leg goes through the wall: it crosses x = 10 only above it
        if (ax - 10) * (bx - 10) < 0 do
          y = ay + (by - ay) * (10 - ax) / (bx - ax)
          assert y > 7.25
        end

        for k <- 0..10 do
          p = {ax + k / 10 * (bx - ax), ay + k / 10 * (by - ay)}
          assert World.free?(world, p, 0.25)
        end
      end
    end

    # they walk in a simulation
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false, walkers: walkers)
    before = Sim.walkers(sim)
    :ok = Sim.run_for(sim, 2.0)
    assert Enum.count(Sim.walkers(sim), fn {id, at} -> at != before[id] end) > 20
    GenServer.stop(sim)
  end

  test "a WDF's crowd section walks in the simulation", %{tmp_dir: dir} do
    world = T.world!(dir, walls: T.box(20, 10), crowd: [count: 12, seed: 4, reach: 5.0])
    # (before the simulation: its walkers become bodies of the world)
    walkers = Crowd.walkers(world, count: 12, seed: 4, reach: 5.0)
    {:ok, sim} = Sim.start_link(world: world, mode: :fast, running: false)
    starts = Map.new(walkers, fn {id, opts} -> {id, hd(opts[:route])} end)
    assert Sim.walkers(sim) == starts
    :ok = Sim.run_for(sim, 1.0)
    assert Enum.count(Sim.walkers(sim), fn {id, at} -> at != starts[id] end) > 6
    GenServer.stop(sim)
  end

  test "bad options and a world without room are named", %{tmp_dir: dir} do
    world = T.world!(dir, walls: T.box(20, 10))

    assert_raise ArgumentError, ~r/Crowd: count: nil is not valid/, fn ->
      Crowd.walkers(world, [])
    end

    assert_raise ArgumentError, ~r/Crowd: speed: \{1, 0\} is not valid/, fn ->
      Crowd.walkers(world, count: 1, speed: {1, 0})
    end

    assert_raise ArgumentError, ~r/no room for a walker's route/, fn ->
      Crowd.walkers(world, count: 1, radius: 6.0)
    end
  end
end
