defmodule ThinkingCap.Examples.WallFollowerTest do
  # The module of the module author's guide (docs/module_guide.md), tested
  # as the guide shows: in lockstep, then driving a simulated robot.
  use ExUnit.Case, async: true

  alias ThinkingCap.Examples.WallFollower
  alias ThinkingCap.Perception.LPS
  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Testing.Sim, as: T

  # a wall along the robot's right, `d` m away, from 2 m behind to 3 m ahead
  defp wall_on_right(d), do: for(i <- 0..50, do: {-2.0 + i * 0.1, -d})

  # a wall across the way, `d` m ahead
  defp wall_ahead(d), do: for(i <- 0..20, do: {d, -1.0 + i * 0.1})

  defp follower(params \\ []) do
    Lockstep.new(
      robot: :r1,
      modules: [follower: {WallFollower, params, period: 0.1}]
    )
  end

  # the command of the next cycle after the LPS made of `points`
  defp command(lock, points) do
    lock = lock |> Lockstep.deliver({:lps, :r1, LPS.from_points(points)}) |> next_cycle()
    {:drive, :r1, %{command: command}} = Lockstep.latest(lock, {:drive, :r1, :_})
    {command, lock}
  end

  defp next_cycle(lock), do: Lockstep.advance(lock, lock.time + 0.1)

  test "stops until it has seen the robot's surroundings" do
    lock = follower() |> next_cycle()
    assert {:drive, :r1, %{command: :stop}} = Lockstep.latest(lock, {:drive, :r1, :_})
  end

  test "keeps the wall's distance: straight on at it, towards a wall too far, away from one too near" do
    lock = follower(distance: 0.5, speed: 0.3)

    assert {{:velocity, v, w}, lock} = command(lock, wall_on_right(0.5))
    assert_in_delta v, 0.3, 1.0e-9
    assert_in_delta w, 0.0, 0.1

    # too far: turn right (clockwise), towards it; too near: left
    assert {{:velocity, _, w}, lock} = command(lock, wall_on_right(1.0))
    assert w < -0.3
    assert {{:velocity, _, w}, _lock} = command(lock, wall_on_right(0.3))
    assert w > 0.1

    # the wall on the left: the mirror image
    lock = follower(side: :left, distance: 0.5)
    mirrored = for {x, y} <- wall_on_right(1.0), do: {x, -y}
    assert {{:velocity, _, w}, _lock} = command(lock, mirrored)
    assert w > 0.3
  end

  test "slows down as an obstacle ahead gets near, stops and turns away within stop_within" do
    lock = follower(speed: 0.4, slow_within: 1.0, stop_within: 0.4)

    assert {{:velocity, fast, _}, lock} = command(lock, wall_on_right(0.5) ++ wall_ahead(2.0))

    assert {{:velocity, half, w_half}, lock} =
             command(lock, wall_on_right(0.5) ++ wall_ahead(0.7))

    assert {{:velocity, stopped, w_stop}, _} =
             command(lock, wall_on_right(0.5) ++ wall_ahead(0.3))

    assert_in_delta fast, 0.4, 1.0e-9
    # halfway between stop_within and slow_within (within a sector's width)
    assert_in_delta half, 0.2, 0.04
    assert stopped == 0.0
    # away from the wall on its right, harder when nearer
    assert 0.0 < w_half and w_half < w_stop
    assert_in_delta w_stop, 1.0, 1.0e-9
  end

  test "live params: taken at the next cycle, checked against the schema and each other" do
    lock = follower(speed: 0.3)
    {{:velocity, v, _}, lock} = command(lock, wall_on_right(0.5))
    assert_in_delta v, 0.3, 1.0e-9

    assert {:ok, lock} = Lockstep.set_param(lock, :follower, :speed, 0.5)
    {{:velocity, v, _}, lock} = command(lock, wall_on_right(0.5))
    assert_in_delta v, 0.5, 1.0e-9

    assert {:param, :r1, %{module: :follower, key: :speed, value: 0.5}} =
             Lockstep.latest(lock, {:param, :r1, :_})

    assert {:error, message} = Lockstep.set_param(lock, :follower, :speed, 3)
    assert message =~ "0.0 to 1.0"
    assert {:error, message} = Lockstep.set_param(lock, :follower, :side, :left)
    assert message =~ "read-only"
    assert {:error, message} = Lockstep.set_param(lock, :follower, :stop_within, 1.5)
    assert message =~ "below slow_within"
    assert Lockstep.params(lock, :follower).stop_within == 0.4
  end

  @rdf Path.expand("../../../../../priv/examples/office_robot.rdf", __DIR__)

  @tag :tmp_dir
  test "drives a simulated robot round a room along its walls, touching none", %{tmp_dir: dir} do
    wdf = T.wdf!(dir, walls: T.box(6, 4))
    {:ok, sim} = Sim.start_link(world: wdf, mode: :fast, running: false, step: 0.05, seed: 3)

    stack = [
      perception: {ThinkingCap.Perception.Fuser, []},
      follower: {WallFollower, [side: :right, distance: 0.6, speed: 0.3], period: 0.1}
    ]

    # heading east, the south wall 0.6 m on its right
    :ok =
      Sim.add_robot(sim, :r,
        rdf: @rdf,
        at: {1.0, 0.6, 0.0},
        controller: {Sim.LockstepController, modules: stack, rdf: @rdf, wdf: wdf}
      )

    # where it is, every simulated second for 90 s
    poses =
      for _ <- 1..90 do
        :ok = Sim.run_for(sim, 1.0)
        {:ok, pose} = Sim.pose(sim, :r)
        pose
      end

    assert Sim.status(sim).blocked == 0

    # it went round, counter-clockwise: along the east wall, the north,
    # the west, and back along the south wall
    east = Enum.find_index(poses, fn {x, y, _} -> x > 5.0 and y > 1.5 end)
    north = Enum.find_index(poses, fn {x, y, _} -> y > 3.0 and x < 3.0 end)
    west = Enum.find_index(poses, fn {x, y, _} -> x < 1.0 and y < 2.0 end)
    south = Enum.find_index(Enum.drop(poses, west || 0), fn {x, y, _} -> y < 1.0 and x > 3.0 end)
    assert east < north and north < west and south != nil

    # and kept to the walls: never far from the nearest one, never on it
    for {x, y, _} <- poses do
      nearest = Enum.min([x, 6 - x, y, 4 - y])
      assert nearest > 0.3 and nearest < 0.9, "#{inspect({x, y})}: #{nearest} m from a wall"
    end
  end
end
