defmodule ThinkingCap.SimTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir

  @laser [
    name: :laser,
    type: :laser,
    range: {0.05, 8.0},
    fov: :math.pi(),
    beams: 181,
    rate: 100
  ]

  defp sim(world, opts \\ []) do
    {:ok, sim} =
      Sim.start_link(Keyword.merge([world: world, mode: :fast, running: false, seed: 1], opts))

    on_exit(fn -> if Process.alive?(sim), do: GenServer.stop(sim) end)
    sim
  end

  # the readings of the next step
  defp next_readings(sim, id) do
    :ok = Sim.step(sim)
    assert_receive {:tc_sim, :readings, ^id, readings}, 1000
    Map.new(readings)
  end

  defp collect(sim, id, steps, sensor) do
    flush(id)

    for _ <- 1..steps do
      :ok = Sim.step(sim)
      assert_receive {:tc_sim, :readings, ^id, readings}, 1000
      Map.new(readings)[sensor]
    end
  end

  defp flush(id) do
    receive do
      {:tc_sim, :readings, ^id, _} -> flush(id)
    after
      0 -> :ok
    end
  end

  describe "sensors against analytic geometry" do
    test "laser beams read the distance to the walls", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {5, 5, 0}, owner: self())
      %{laser: scan} = next_readings(sim, :r)

      assert length(scan.ranges) == 181
      assert_in_delta scan.angle_min, -:math.pi() / 2, 1.0e-9
      assert_in_delta scan.angle_increment, :math.pi() / 180, 1.0e-9
      # straight ahead, straight right, and 30° left (hits x = 10 at 5 / cos 30°)
      assert_in_delta Enum.at(scan.ranges, 90), 5.0, 1.0e-6
      assert_in_delta Enum.at(scan.ranges, 0), 5.0, 1.0e-6
      assert_in_delta Enum.at(scan.ranges, 120), 5.0 / :math.cos(:math.pi() / 6), 1.0e-6
    end

    test "a sonar ring reads each wall from its transducer", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 8)))

      sonar = [
        name: :sonar,
        type: :sonar,
        count: 4,
        ring_radius: 0.1,
        range: {0.05, 5.0},
        fov: 0.26,
        rays: 3,
        rate: 100
      ]

      robot = T.robot!(dir, sensors: [sonar])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {6, 5, 0}, owner: self())
      %{sonar: s} = next_readings(sim, :r)
      # east wall 4 m away, north 3, west 6 (beyond 5 m: max range), south 5
      assert [east, north, west, south] = s.ranges
      assert_in_delta east, 3.9, 1.0e-6
      assert_in_delta north, 2.9, 1.0e-6
      assert west == 5.0
      assert_in_delta south, 4.9, 1.0e-6
      assert_in_delta Enum.at(s.headings, 1), :math.pi() / 2, 1.0e-9
    end

    test "a sonar ray hitting a wall at a shallow angle reads max range", %{tmp_dir: dir} do
      # one long wall along y = 1; the transducer looks along it at 20°
      sim = sim(T.world!(dir, walls: [{{-20, 1}, {20, 1}}]))

      sonar = [
        name: :sonar,
        type: :sonar,
        range: {0.05, 5.0},
        fov: 0.01,
        rays: 1,
        max_reflections: 0,
        critical_angle: 0.26,
        rate: 100
      ]

      robot = T.robot!(dir, sensors: [sonar], footprint: [radius: 0.1])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {0, 0, 0.35}, owner: self())
      %{sonar: %{ranges: [r]}} = next_readings(sim, :r)
      # the ray meets the wall 1/sin(0.35) m away, 70° off the normal: no echo
      assert r == 5.0

      # looking at the wall almost head-on, the echo comes back
      :ok = Sim.remove_robot(sim, :r)
      :ok = Sim.add_robot(sim, :r2, description: robot, at: {0, 0, 1.45}, owner: self())
      %{sonar: %{ranges: [r2]}} = next_readings(sim, :r2)
      assert_in_delta r2, 1 / :math.sin(1.45), 1.0e-6
    end

    test "the beacon sensor gives range and bearing to visible beacons", %{tmp_dir: dir} do
      sim =
        sim(
          T.world!(dir,
            walls: T.box(10, 10) ++ [{{6, 1}, {6, 4.5}}],
            beacons: [[name: :a, at: {8, 9}], [name: :hidden, at: {8, 2}]]
          )
        )

      beacons = [name: :beacons, type: :beacon_laser, range: {0.2, 15.0}, fov: 6.28, rate: 100]
      robot = T.robot!(dir, sensors: [beacons])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {5, 5, 0.5}, owner: self())
      %{beacons: %{detections: detections}} = next_readings(sim, :r)
      # :hidden is behind the wall x = 6
      assert [%{id: :a, range: range, bearing: bearing}] = detections
      assert_in_delta range, 5.0, 1.0e-9
      assert_in_delta bearing, :math.atan2(4, 3) - 0.5, 1.0e-9
    end

    test "robots see each other", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :a, description: robot, at: {2, 5, 0}, owner: self())
      :ok = Sim.add_robot(sim, :b, description: robot, at: {4, 5, 0}, owner: self())
      :ok = Sim.step(sim)
      assert_receive {:tc_sim, :readings, :a, readings}
      assert_in_delta Enum.at(Map.new(readings).laser.ranges, 90), 4 - 0.2 - 2, 1.0e-6
      # a robot's start pose must be free of the others
      assert {:error, message} = Sim.add_robot(sim, :c, description: robot, at: {4.1, 5, 0})
      assert message =~ "not free"
    end

    test "a reading sees robots and walkers where they stand after the step's moves", %{
      tmp_dir: dir
    } do
      sim = sim(T.world!(dir, walls: T.box(12, 10)))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :a, description: robot, at: {2, 5, 0}, owner: self())
      :ok = Sim.add_robot(sim, :b, description: robot, at: {4, 5, 0}, owner: self())
      # a walker coming down towards :a's left side, on x = 2
      :ok = Sim.add_walker(sim, :person, route: [{2, 9}, {2, 6.5}], speed: 1.0)
      Sim.command(sim, :b, {:velocity, 0.5, 0.0})
      flush(:a)

      moved =
        for _ <- 1..6 do
          :ok = Sim.step(sim)
          assert_receive {:tc_sim, :readings, :a, readings}, 1000
          ranges = Map.new(readings).laser.ranges
          {:ok, {bx, 5.0, _}} = Sim.pose(sim, :b)
          %{person: {2.0, wy}} = Sim.walkers(sim)
          # ahead: :b (radius 0.2) where it stands now; left: the walker (0.25)
          assert_in_delta Enum.at(ranges, 90), bx - 0.2 - 2, 1.0e-6
          assert_in_delta Enum.at(ranges, 180), wy - 0.25 - 5, 1.0e-6
          {bx, wy}
        end

      # both moved at every step, so a reading a step late would differ
      for {{b0, w0}, {b1, w1}} <- Enum.zip(moved, tl(moved)), do: assert(b1 > b0 and w1 < w0)
    end

    test "a publishing simulation writes readings and true poses to the blackboard", %{
      tmp_dir: dir
    } do
      sim = sim(T.world!(dir, walls: T.box(10, 10)), publish: true)
      id = :"pub#{System.unique_integer([:positive])}"
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, id, description: robot, at: {5, 5, 0})
      :ok = Sim.step(sim, 2)

      assert {:ok, {:laser, ^id, %{ranges: ranges}}} =
               ThinkingCap.Blackboard.rdp({:laser, id, :_})

      assert_in_delta Enum.at(ranges, 90), 5.0, 1.0e-6
      # latest values: one tuple per robot and sensor
      assert [_] = ThinkingCap.Blackboard.rd_all({:laser, id, :_})

      assert {:ok, {:sim_pose, ^id, %{pose: {5.0, 5.0, +0.0}}}} =
               ThinkingCap.Blackboard.rdp({:sim_pose, id, :_})
    end

    test "a closed door is a wall; opened while running, the laser sees through", %{
      tmp_dir: dir
    } do
      walls = T.box(10, 10) ++ [{{5, 0}, {5, 4}}, {{5, 6}, {5, 10}}]
      door = [name: :d, from: {5, 4}, to: {5, 6}, open: false]
      sim = sim(T.world!(dir, walls: walls, doors: [door]))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {3, 5, 0}, owner: self())
      assert_in_delta Enum.at(next_readings(sim, :r).laser.ranges, 90), 2.0, 1.0e-6
      :ok = Sim.set_door(sim, :d, true)
      assert_in_delta Enum.at(next_readings(sim, :r).laser.ranges, 90), 7.0, 1.0e-6
      assert {:error, _} = Sim.set_door(sim, :nope, true)
    end
  end

  describe "motion" do
    test "constant velocity commands follow closed-form arcs and turns", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))

      robot =
        T.robot!(dir,
          kinematics: [
            type: :differential,
            wheel_radius: 0.05,
            wheel_separation: 0.3,
            max_speed: 1.0,
            max_turn_rate: 2.0,
            max_acceleration: 1000.0
          ]
        )

      :ok = Sim.add_robot(sim, :arc, description: robot, at: {5, 3, 0})
      :ok = Sim.add_robot(sim, :spin, description: robot, at: {2, 2, 0})
      Sim.command(sim, :arc, {:velocity, 0.5, 0.5})
      Sim.command(sim, :spin, {:velocity, 0.0, 1.0})
      :ok = Sim.step(sim, 300)
      t = Sim.time(sim)
      assert_in_delta t, 3.0, 1.0e-9

      # radius v / omega = 1 m around (5, 4)
      {:ok, {x, y, th}} = Sim.pose(sim, :arc)
      assert_in_delta x, 5 + :math.sin(0.5 * t), 1.0e-6
      assert_in_delta y, 3 + 1 - :math.cos(0.5 * t), 1.0e-6
      assert_in_delta th, 0.5 * t, 1.0e-6
      # no odometry error in this robot: odometry is the true motion
      {:ok, {ox, oy, oth}} = Sim.odometry(sim, :arc)
      assert_in_delta ox, x - 5, 1.0e-6
      assert_in_delta oy, y - 3, 1.0e-6
      assert_in_delta oth, th, 1.0e-6

      {:ok, {sx, sy, sth}} = Sim.pose(sim, :spin)
      assert {sx, sy} == {2.0, 2.0}
      assert_in_delta sth, 3.0, 1.0e-6
    end

    test "an Ackermann car and a tricycle turn on their closed-form radius", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(30, 30)))

      car =
        T.robot!(dir,
          footprint: [polygon: [{-0.5, -0.4}, {1.5, -0.4}, {1.5, 0.4}, {-0.5, 0.4}]],
          kinematics: [
            type: :ackermann,
            wheelbase: 1.0,
            track: 0.6,
            max_steering: 0.6,
            max_speed: 2.0,
            max_turn_rate: 2.0,
            max_acceleration: 1000.0
          ]
        )

      trike =
        T.robot!(dir,
          kinematics: [
            type: :tricycle,
            wheelbase: 0.8,
            max_steering: 1.2,
            max_speed: 2.0,
            max_turn_rate: 2.0,
            max_acceleration: 1000.0
          ]
        )

      :ok = Sim.add_robot(sim, :car, description: car, at: {10, 5, 0})
      :ok = Sim.add_robot(sim, :trike, description: trike, at: {20, 20, 0})
      Sim.command(sim, :car, {:steer, 0.5, 0.3})
      Sim.command(sim, :trike, {:steer, 0.4, 0.5})
      :ok = Sim.step(sim, 500)
      t = 5.0

      # the rear axle runs on a circle of radius L / tan(delta)
      r = 1.0 / :math.tan(0.3)
      {:ok, {x, y, th}} = Sim.pose(sim, :car)
      assert_in_delta th, 0.5 * t / r, 1.0e-6
      assert_in_delta x, 10 + r * :math.sin(th), 1.0e-6
      assert_in_delta y, 5 + r * (1 - :math.cos(th)), 1.0e-6

      # the tricycle's steered wheel drives: v = u cos(delta), omega = u sin(delta) / L
      {v, w} = {0.4 * :math.cos(0.5), 0.4 * :math.sin(0.5) / 0.8}
      {:ok, {x, y, th}} = Sim.pose(sim, :trike)
      assert_in_delta th, w * t, 1.0e-6
      assert_in_delta x, 20 + v / w * :math.sin(w * t), 1.0e-6
      assert_in_delta y, 20 + v / w * (1 - :math.cos(w * t)), 1.0e-6
    end

    test "obstacles are solid: seen by the laser, no place to start", %{tmp_dir: dir} do
      shelf = [name: :shelf, polygon: [{6, 4}, {8, 4}, {8, 6}, {6, 6}]]
      sim = sim(T.world!(dir, walls: T.box(10, 10), obstacles: [shelf]))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {3, 5, 0}, owner: self())
      assert_in_delta Enum.at(next_readings(sim, :r).laser.ranges, 90), 3.0, 1.0e-6
      assert {:error, _} = Sim.add_robot(sim, :inside, description: robot, at: {7, 5, 0})
    end

    test "a robot driven into a wall stops at it with its bumper pressed", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      robot = T.robot!(dir, sensors: [[name: :bumper, type: :bumper, rate: 100]])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {8, 5, 0}, owner: self())
      Sim.command(sim, :r, {:velocity, 0.5, 0.0})
      :ok = Sim.run_for(sim, 10)
      {:ok, {x, 5.0, +0.0}} = Sim.pose(sim, :r)
      assert x <= 10 - 0.2 and x > 10 - 0.2 - 0.01
      flush = collect(sim, :r, 1, :bumper)
      assert [%{pressed: true}] = flush
      # backing off frees it
      Sim.command(sim, :r, {:velocity, -0.5, 0.0})
      :ok = Sim.step(sim, 5)
      assert [%{pressed: false}] = collect(sim, :r, 1, :bumper)
    end
  end

  describe "contacts between robots" do
    test "robots driven into each other stop at contact, bumpers pressed, never overlapping", %{
      tmp_dir: dir
    } do
      # eight robots on a circle, all driving to its centre, with the
      # benchmark's 0.1 s step (each moves up to 5 cm a step)
      sim = sim(T.world!(dir, walls: T.box(10, 10)), step: 0.1)
      robot = T.robot!(dir, sensors: [[name: :bumper, type: :bumper, rate: 10]])
      ids = for k <- 0..7, do: :"c#{k}"

      for {id, k} <- Enum.with_index(ids) do
        a = k * :math.pi() / 4
        at = {5 + 3 * :math.cos(a), 5 + 3 * :math.sin(a), a + :math.pi()}
        :ok = Sim.add_robot(sim, id, description: robot, at: at, owner: self())
        Sim.command(sim, id, {:velocity, 0.5, 0.0})
      end

      for _ <- 1..80 do
        :ok = Sim.step(sim)
        poses = Map.values(Sim.robots(sim))

        for {x1, y1, _} = p <- poses, {x2, y2, _} = q <- poses, p < q do
          assert :math.sqrt((x1 - x2) ** 2 + (y1 - y2) ** 2) >= 0.4 - 1.0e-9
        end
      end

      # they met: each touches a neighbour (within one step) and feels it
      poses = Sim.robots(sim)

      for {id, {x, y, _}} <- poses do
        nearest =
          for(
            {other, {u, v, _}} <- poses,
            other != id,
            do: :math.sqrt((x - u) ** 2 + (y - v) ** 2)
          )
          |> Enum.min()

        assert nearest < 0.4 + 0.05 + 1.0e-9
      end

      for id <- ids, do: flush(id)
      :ok = Sim.step(sim)

      for id <- ids do
        assert_receive {:tc_sim, :readings, ^id, readings}, 1000
        assert %{pressed: true} = Map.new(readings).bumper
      end
    end
  end

  describe "shards" do
    test "shards start as robots come; the run does not depend on how robots are split", %{
      tmp_dir: dir
    } do
      world = T.world!(dir, walls: T.box(30, 30))
      robot = T.robot!(dir, sensors: [@laser, [name: :bumper, type: :bumper, rate: 10]])

      # 70 wandering robots, 10 pairs driving into each other and a walker; the trajectories (true poses and odometry after every
      # step), rays and blocked robot-steps, for one split and another
      run = fn opts ->
        sim = sim(world, [step: 0.1, walkers: [p: [route: [{2, 15}, {28, 15}]]]] ++ opts)

        for k <- 0..69 do
          at = {1 + rem(k, 10) * 2.8, 1 + div(k, 10) * 2.8 + 0.5, k * 0.7}
          :ok = Sim.add_robot(sim, :"s#{k}", description: robot, at: at, controller: Sim.Wander)
        end

        # and pairs driving head-on into each other
        for k <- 0..9, {id, x, th} <- [{:a, 2.0, 0.0}, {:b, 2.6, :math.pi()}] do
          robot_id = :"#{id}#{k}"
          :ok = Sim.add_robot(sim, robot_id, description: robot, at: {x + 2.5 * k, 28, th})
          Sim.command(sim, robot_id, {:velocity, 0.5, 0.0})
        end

        trajectory =
          for _ <- 1..30 do
            :ok = Sim.step(sim)
            odom = for k <- [0, 33, 69], do: Sim.odometry(sim, :"s#{k}")
            {Sim.robots(sim), odom, Sim.walkers(sim)}
          end

        status = Sim.status(sim)
        GenServer.stop(sim)
        {trajectory, status}
      end

      {one, status_1} = run.(shards: 1, per_shard: 1000)
      assert status_1.shards == 1
      {many, status_many} = run.(shards: 3, per_shard: 4, regroup_every: 7)
      assert status_many.shards == 24
      assert status_many.handovers > 0
      {default, status_default} = run.([])
      assert status_default.shards > 1

      assert one == many
      assert one == default
      assert status_1.rays == status_many.rays and status_1.rays > 0
      assert status_1.blocked == status_many.blocked and status_1.blocked > 0

      # they moved
      {poses, _, _} = List.last(one)

      assert Enum.count(poses, fn {_, {x, _, _}} ->
               abs(x - 1 - round((x - 1) / 2.8) * 2.8) > 0.01
             end) > 10
    end

    test "walkers that cannot start are refused with the reason", %{tmp_dir: dir} do
      world = T.world!(dir, walls: T.box(5, 5))
      Process.flag(:trap_exit, true)
      route = [route: [{1, 1}, {4, 1}]]

      assert {:error, "ThinkingCap.Sim: walker :p exists already"} =
               Sim.start_link(world: world, walkers: [p: route, p: route])

      assert {:error, "ThinkingCap.Sim: walker :q: {0.0, 2.0} is not free"} =
               Sim.start_link(world: world, walkers: [q: [route: [{0, 2}, {1, 1}]]])
    end

    test "shard options are checked", %{tmp_dir: dir} do
      world = T.world!(dir, walls: T.box(5, 5))
      Process.flag(:trap_exit, true)

      assert {:error, "ThinkingCap.Sim: per_shard: 0 is not a positive integer"} =
               Sim.start_link(world: world, per_shard: 0)

      assert {:error, "ThinkingCap.Sim: shards: :x is not a positive integer"} =
               Sim.start_link(world: world, shards: :x)
    end
  end

  describe "walkers" do
    test "a walker walks its route back and forth, seen by the laser", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      robot = T.robot!(dir, sensors: [@laser])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {1, 5, 0}, owner: self())
      :ok = Sim.add_walker(sim, :person, route: [{6, 2}, {6, 8}], speed: 1.0)
      assert Sim.walkers(sim) == %{person: {6.0, 2.0}}

      # at y = 5 after 3 s, right in front of the robot: a disc of 0.25 m at 5 m
      :ok = Sim.run_for(sim, 3.0)
      {:person, {6.0, y}} = Enum.at(Sim.walkers(sim), 0)
      assert_in_delta y, 5.0, 0.02
      [scan] = collect(sim, :r, 1, :laser)
      assert_in_delta Enum.at(scan.ranges, 90), 5.0 - 0.25, 0.05

      # at the end of the route it turns back
      :ok = Sim.run_for(sim, 4.0)
      {:person, {6.0, y}} = Enum.at(Sim.walkers(sim), 0)
      assert_in_delta y, 7.0, 0.05
      assert Sim.status(sim).walkers == 1
    end

    test "a robot driving into a walker is stopped; a walker waits for a robot in its way", %{
      tmp_dir: dir
    } do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      robot = T.robot!(dir, sensors: [[name: :bumper, type: :bumper, rate: 100]])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {3, 5, 0}, owner: self())
      # a walker standing still on a route it cannot pass: the robot is on it
      :ok = Sim.add_walker(sim, :person, route: [{6, 5}, {1, 5}], speed: 0.5)
      Sim.command(sim, :r, {:velocity, 0.5, 0.0})
      :ok = Sim.run_for(sim, 6.0)
      {:ok, {x, _, _}} = Sim.pose(sim, :r)
      {:person, {px, _}} = Enum.at(Sim.walkers(sim), 0)
      # they met and neither went through the other
      assert px - x >= 0.2 + 0.25 - 0.01
      assert Sim.status(sim).blocked > 0
      assert [%{pressed: true}] = collect(sim, :r, 1, :bumper)
    end

    test "walkers come back to their start on reset; bad routes are refused", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)))
      :ok = Sim.add_walker(sim, :a, route: [{2, 2}, {8, 2}], loop: true)
      :ok = Sim.run_for(sim, 2.0)
      refute Sim.walkers(sim).a == {2.0, 2.0}
      :ok = Sim.reset(sim)
      assert Sim.walkers(sim).a == {2.0, 2.0}

      assert {:error, message} = Sim.add_walker(sim, :b, route: [{2, 2}])
      assert message =~ "route"
      assert {:error, message} = Sim.add_walker(sim, :a, route: [{3, 3}, {4, 4}])
      assert message =~ "exists"
      assert {:error, :no_walker} = Sim.remove_walker(sim, :nobody)
      assert :ok = Sim.remove_walker(sim, :a)
      assert Sim.walkers(sim) == %{}
    end
  end

  describe "kidnapping" do
    test "a teleported robot is elsewhere while its odometry carries on", %{tmp_dir: dir} do
      shelf = [name: :shelf, polygon: [{6, 4}, {8, 4}, {8, 6}, {6, 6}]]
      sim = sim(T.world!(dir, walls: T.box(10, 10), obstacles: [shelf]))
      robot = T.robot!(dir, sensors: [@laser, [name: :odom, type: :odometry, rate: 100]])
      :ok = Sim.add_robot(sim, :r, description: robot, at: {2, 2, 0}, owner: self())
      Sim.command(sim, :r, {:velocity, 0.5, 0.0})
      :ok = Sim.run_for(sim, 1.0)
      {:ok, odom} = Sim.odometry(sim, :r)

      assert :ok = Sim.teleport(sim, :r, {3, 8, :math.pi()})
      assert {:ok, {3.0, 8.0, th}} = Sim.pose(sim, :r)
      assert_in_delta th, :math.pi(), 1.0e-9
      assert {:ok, ^odom} = Sim.odometry(sim, :r)
      # the laser now sees the west wall 3 m ahead
      [scan] = collect(sim, :r, 1, :laser)
      assert_in_delta Enum.at(scan.ranges, 90), 3.0, 0.02

      assert {:error, message} = Sim.teleport(sim, :r, {7, 5, 0})
      assert message =~ "overlaps"
      assert {:error, :no_robot} = Sim.teleport(sim, :nobody, {3, 3, 0})
    end
  end

  describe "clock" do
    test "pause, single step, reset and determinism for a seed", %{tmp_dir: dir} do
      world = T.world!(dir, walls: T.box(10, 10) ++ [{{3, 3}, {7, 7}}])

      robot =
        T.robot!(dir,
          sensors: [Keyword.put(@laser, :noise, stddev: 0.02)],
          odometry_error: [slip: 0.05, turn_slip: 0.05, wheel_diameter_ratio: 1.01]
        )

      run = fn seed ->
        sim = sim(world, seed: seed)

        for {id, at} <- [a: {1, 1, 0}, b: {8, 2, 2}, c: {2, 8, -1}],
            do: :ok = Sim.add_robot(sim, id, description: robot, at: at, controller: Sim.Wander)

        :ok = Sim.run_for(sim, 20)
        {sim, Sim.robots(sim)}
      end

      {sim, poses} = run.(5)
      {_, same} = run.(5)
      {_, other} = run.(6)
      assert poses == same
      assert poses != other
      # they moved
      assert poses.a != {1.0, 1.0, 0.0}

      :ok = Sim.reset(sim)
      assert Sim.time(sim) == 0.0
      assert Sim.robots(sim).a == {1.0, 1.0, 0.0}
      :ok = Sim.run_for(sim, 20)
      assert Sim.robots(sim) == poses
    end

    test "real-time mode steps on the timing worker and pauses", %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)), mode: :realtime, running: true)
      # stepping (on a loaded machine the worker's first releases may wait)
      ThinkingCap.Testing.Cluster.wait_until(fn -> Sim.time(sim) > 0 end)
      :ok = Sim.pause(sim)
      t2 = Sim.time(sim)
      Process.sleep(100)
      assert Sim.time(sim) == t2
      :ok = Sim.step(sim, 3)
      assert_in_delta Sim.time(sim), t2 + 0.03, 1.0e-9
      :ok = Sim.resume(sim)
      Process.sleep(100)
      assert Sim.time(sim) > t2 + 0.03
      assert %{mode: :realtime} = Sim.status(sim)
    end

    test "real-time mode at a speed releases a step every step / speed seconds",
         %{tmp_dir: dir} do
      sim = sim(T.world!(dir, walls: T.box(10, 10)), mode: :realtime, running: true, speed: 0.25)
      assert %{speed: 0.25, step: 0.01} = Sim.status(sim)
      ThinkingCap.Testing.Cluster.wait_until(fn -> Sim.time(sim) > 0 end)
      t0 = Sim.time(sim)
      Process.sleep(400)
      # at most 400 ms / 40 ms = 10 steps (and one at the window's edge)
      assert Sim.time(sim) - t0 <= 0.11 + 1.0e-9
    end

    test "bad options are refused with the reason" do
      Process.flag(:trap_exit, true)
      assert {:error, message} = Sim.start_link(world: "/nonexistent.wdf")
      assert message =~ "/nonexistent.wdf"
      assert {:error, message} = Sim.start_link(world: "/x.wdf", mode: :slow)
      assert message =~ "mode"
      assert {:error, message} = Sim.start_link(world: "/x.wdf", speed: 0)
      assert message =~ "speed"
    end
  end
end
