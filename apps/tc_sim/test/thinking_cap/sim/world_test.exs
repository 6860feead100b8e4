defmodule ThinkingCap.Sim.WorldTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Sim.World

  @wdf Path.expand("../../../../../priv/examples/fleet.wdf", __DIR__)

  test "known_free? is true only in the cells the map knows to be free" do
    {:ok, world} = World.load(@wdf)
    grid = world.wdf.grid
    {ox, oy, _} = grid.origin
    centre = fn {c, r} -> {ox + (c + 0.5) * grid.resolution, oy + (r + 0.5) * grid.resolution} end
    cells = for r <- 0..(grid.height - 1)//7, c <- 0..(grid.width - 1)//7, do: {c, r}
    by_value = Enum.group_by(cells, fn {c, r} -> RosMap.cell(grid, c, r) end)

    assert Enum.all?(Enum.take(by_value[0], 50), &World.known_free?(world, centre.(&1)))

    assert Map.keys(by_value) -- [0] != []

    for value <- Map.keys(by_value) -- [0] do
      refute Enum.any?(Enum.take(by_value[value], 50), &World.known_free?(world, centre.(&1)))
    end

    refute World.known_free?(world, {ox - 1.0, oy})
  end

  test "random_pose draws within the bounds, any heading, the same for the same seed" do
    {:ok, world} = World.load(@wdf)
    {{x0, y0}, {x1, y1}} = world.bounds

    draw = fn seed ->
      rng = :rand.seed_s(:exsss, {seed, 1, 1})

      {poses, _} = Enum.map_reduce(1..200, rng, fn _, rng -> World.random_pose(world, rng) end)

      poses
    end

    poses = draw.(3)
    assert poses == draw.(3)
    refute poses == draw.(4)

    assert Enum.all?(poses, fn {x, y, th} ->
             x >= x0 and x <= x1 and y >= y0 and y <= y1 and th >= -:math.pi() and
               th <= :math.pi()
           end)

    # spread over the bounds, not stuck in a corner
    {xs, ys} = {Enum.map(poses, &elem(&1, 0)), Enum.map(poses, &elem(&1, 1))}
    assert Enum.max(xs) - Enum.min(xs) > 0.8 * (x1 - x0)
    assert Enum.max(ys) - Enum.min(ys) > 0.8 * (y1 - y0)
  end

  test "a world without a map is free everywhere it knows" do
    {:ok, world} = World.from_wdf(%ThinkingCap.Config.WDF{name: "empty"})
    assert World.known_free?(world, {3.0, 4.0})
  end
end
