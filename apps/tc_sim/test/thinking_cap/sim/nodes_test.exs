defmodule ThinkingCap.Sim.NodesTest do
  # A simulation spread over two BEAM nodes (the :nodes option): two real
  # local nodes started with OTP's :peer (ThinkingCap.Testing.Cluster),
  # the coordinator on the first. The same runs on one node are the
  # reference: every pose, odometry and reading must be equal.
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim
  alias ThinkingCap.Sim.Core.Ghosts
  alias ThinkingCap.Testing.{Cluster, Cruise, FleetRun}
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir
  @moduletag timeout: 180_000
  @fleet_wdf Path.expand("../../../../../priv/examples/fleet.wdf", __DIR__)
  @fleet_rdf Path.expand("../../../../../priv/examples/fleet_robot.rdf", __DIR__)

  setup_all do
    nodes = Cluster.start(2, apps: [])
    on_exit(fn -> Cluster.stop(nodes) end)
    %{nodes: nodes}
  end

  describe "a handover across a region border" do
    # a 20 m x 4 m hall cut at x = 10: the mover drives east from x = 2
    # past a robot parked on each side, its all-round laser seeing them
    setup %{tmp_dir: dir} do
      wdf = T.wdf!(dir, walls: T.box(20, 4))

      laser = [
        name: :laser,
        type: :laser,
        range: {0.05, 8.0},
        fov: 6.0,
        beams: 121,
        rate: 10,
        noise: [stddev: 0.01]
      ]

      robot =
        T.robot!(dir,
          sensors: [laser, [name: :odom, type: :odometry, rate: 10]],
          odometry_error: [slip: 0.02, turn_slip: 0.02]
        )

      %{wdf: wdf, robot: robot}
    end

    test "the robot is handed to the other node whole, and senses as on one node", ctx do
      [a, b] = ctx.nodes
      nodes = [a.node, b.node]

      two =
        run_hall(
          ctx,
          fn opts -> Cluster.call(a, Sim, :start, [opts]) end,
          fn m, f, args ->
            Cluster.call(a, m, f, args)
          end,
          nodes: nodes,
          borders: [10.0],
          regroup_every: 1
        )

      one = run_hall(ctx, &Sim.start/1, &apply/3, [])

      # it started on the first node, west of the border, and ended on the
      # second, east of it; the parked robots stayed where they were
      assert hd(two.placements) == %{mover: a.node, west: a.node, east: b.node}
      assert List.last(two.placements) == %{mover: b.node, west: a.node, east: b.node}
      {x, _, _} = List.last(two.samples).pose
      assert x > 11.0
      assert two.status.node_handovers == 1
      assert one.status.node_handovers == 0

      # while on the first node it saw the robot parked on the second (a
      # ghost): straight ahead, the laser's middle beam, at 7.6 m from
      # x = 7, less than the wall 13 m away
      at_7 = Enum.find(two.samples, fn %{pose: {x, _, _}} -> x > 6.9 end)
      assert at_7.placement == a.node
      ahead = Enum.at(at_7.laser, 60)
      assert_in_delta ahead, 15.0 - 0.2 - elem(at_7.pose, 0), 0.1

      # every sample equal: pose, odometry and laser, before and after
      assert length(two.samples) == length(one.samples)

      for {s2, s1} <- Enum.zip(two.samples, one.samples),
          do: assert(Map.delete(s2, :placement) == Map.delete(s1, :placement))
    end
  end

  describe "doors and reset across nodes" do
    test "a door opened reaches every region; reset closes it and puts the robots back", ctx do
      [a, b] = ctx.nodes
      dir = ctx.tmp_dir
      door = [name: :d, from: {12, 0}, to: {12, 4}, open: false]
      wdf = T.wdf!(dir, walls: T.box(20, 4), doors: [door])
      laser = [name: :laser, type: :laser, range: {0.05, 8.0}, fov: 3.0, beams: 61, rate: 10]
      robot = T.robot!(dir, sensors: [laser])
      call = fn f, args -> Cluster.call(a, Sim, f, args) end

      {:ok, sim} =
        call.(:start, [
          [world: wdf, mode: :fast, running: false, step: 0.1, nodes: [a.node, b.node]] ++
            [borders: [10.0]]
        ])

      try do
        for {id, at} <- [west: {5.0, 2.0, 0.0}, east: {15.0, 2.0, :math.pi()}] do
          :ok =
            call.(:add_robot, [
              sim,
              id,
              [description: robot, at: at, controller: {Cruise, [command: :stop]}]
            ])
        end

        assert call.(:placement, [sim]) == %{west: a.node, east: b.node}

        ahead = fn ->
          :ok = call.(:step, [sim, 1])

          for id <- [:west, :east] do
            {:ok, c} = call.(:controller_state, [sim, id])
            Enum.at(c.readings.laser.ranges, 30)
          end
        end

        # closed: each sees the door; open: each sees the other robot
        # (a ghost of the other node), 9.6 m away, past the laser's 8 m
        [w, e] = ahead.()
        assert_in_delta w, 7.0, 1.0e-6
        assert_in_delta e, 3.0, 1.0e-6
        :ok = call.(:set_door, [sim, :d, true])
        assert ahead.() == [8.0, 8.0]

        :ok = call.(:teleport, [sim, :west, {9.0, 2.0, 0.0}])
        [w, e] = ahead.()
        assert_in_delta w, 15.0 - 0.2 - 9.0, 1.0e-6
        assert_in_delta e, 15.0 - 9.0 - 0.2, 1.0e-6
        # a place taken by a robot of the other node is refused
        assert {:error, _} = call.(:teleport, [sim, :west, {15.1, 2.0, 0.0}])

        :ok = call.(:reset, [sim])
        assert call.(:time, [sim]) == 0.0
        assert {:ok, {5.0, 2.0, 0.0}} = call.(:pose, [sim, :west])
        [w, e] = ahead.()
        assert_in_delta w, 7.0, 1.0e-6
        assert_in_delta e, 3.0, 1.0e-6
      after
        Cluster.call(a, GenServer, :stop, [sim])
      end
    end
  end

  describe "a node that goes down" do
    test "takes the simulation and its regions down with it", %{nodes: [a, _], tmp_dir: dir} do
      [c] = Cluster.start(1, apps: [], cookie: Cluster.cookie(a))
      on_exit(fn -> Cluster.stop(c) end)
      true = Cluster.connect(a, c)
      wdf = T.wdf!(dir, walls: T.box(20, 4))

      {:ok, sim} =
        Cluster.call(a, Sim, :start, [
          [world: wdf, mode: :fast, running: false, nodes: [a.node, c.node], borders: [10.0]]
        ])

      # the regions on node a: GenServers started from Core.Region
      regions = fn ->
        for pid <- Cluster.call(a, Process, :list, []),
            {:dictionary, d} <- [Cluster.call(a, Process, :info, [pid, :dictionary])],
            d[:"$initial_call"] == {ThinkingCap.Sim.Core.Region, :init, 1},
            do: pid
      end

      assert length(regions.()) == 1
      assert Cluster.call(a, Sim, :step, [sim, 5]) == :ok

      :ok = Cluster.kill(c)
      Cluster.wait_until(fn -> not Cluster.call(a, Process, :alive?, [sim]) end)
      Cluster.wait_until(fn -> regions.() == [] end)
    end
  end

  describe "a fleet across two nodes" do
    test "every trajectory equals the one-node run's with the same seed", %{nodes: [a, b]} do
      {:ok, d} = ThinkingCap.Robot.Description.load(@fleet_rdf)
      {:ok, wdf} = ThinkingCap.Config.read(@fleet_wdf)
      # a smaller crowd than the example's, on the same map
      wdf = %{wdf | crowd: %{wdf.crowd | count: 8}}

      opts = [
        world: wdf,
        description: d,
        robots: 40,
        seconds: 20.0,
        sample_every: 2.0,
        seed: 11
      ]

      one = FleetRun.run(opts)

      two =
        Cluster.call(
          a,
          FleetRun,
          :run,
          [
            opts ++
              [
                sim: [nodes: [a.node, b.node], regroup_every: 10, shards: 2],
                cpu_nodes: [a.node, b.node]
              ]
          ],
          120_000
        )

      assert two.status.nodes == [a.node, b.node]
      assert one.status.walkers == 8 and two.status.walkers == 8
      # both nodes step robots, robots crossed the border, and each node
      # held ghosts of the other's
      final = List.last(two.placements)
      assert final |> Map.values() |> Enum.uniq() |> Enum.sort() == Enum.sort([a.node, b.node])
      assert two.status.node_handovers > 0
      # each node's CPU time while stepping, for the bench's cost a step
      assert Map.keys(two.node_cpu) |> Enum.sort() == Enum.sort([a.node, b.node])
      assert Enum.all?(Map.values(two.node_cpu), &(&1 > 0))
      assert one.node_cpu == %{}
      assert two.status.ghosts > 0
      # the robots moved
      assert Enum.count(List.last(one.samples), fn {id, p} -> p != hd(one.samples)[id] end) > 30

      assert length(two.samples) == 10
      assert two.samples == one.samples
      assert two.status.rays == one.status.rays
      assert two.status.blocked == one.status.blocked
    end
  end

  describe "ghosts" do
    test "a region holds its robots and every other body within reach of them" do
      rec = &Sim.Raycast.body_record/4
      own = %{a: [rec.(0, 1.0, 1.0, 0.2) <> rec.(1, 4.0, 1.0, 0.2)], b: [rec.(2, 9.0, 1.0, 0.2)]}
      walkers = rec.(3, 7.2, 1.0, 0.25) <> rec.(4, 30.0, 1.0, 0.25)
      bodies = Ghosts.bodies(own, walkers, 3.0)

      ids = fn bin -> for <<i::float-native-64, _::binary-size(24) <- bin>>, do: trunc(i) end
      # a: its two robots (box x 1..4, grown to -2..7) and the walker at
      # 7.2 whose disc reaches 6.95; b: its robot and the walker and a's
      # robot at 4 (box 6..12: 4.2 is out, 7.2 in)
      assert Enum.sort(ids.(bodies.a)) == [0, 1, 3]
      assert Enum.sort(ids.(bodies.b)) == [2, 3]
      assert Ghosts.count(bodies.a) == 3
      # a region with no robot needs no body
      assert Ghosts.bodies(%{a: [], b: own.b}, walkers, 3.0).a == <<>>
    end

    test "the records' box and the records within a box, as the plain rule says (50 seeds)" do
      for seed <- 1..50 do
        :rand.seed(:exsss, {seed, 1, 1})

        discs =
          for i <- 0..:rand.uniform(40),
              do: {i, 20 * :rand.uniform(), 20 * :rand.uniform(), :rand.uniform()}

        bin = for {i, x, y, r} <- discs, into: <<>>, do: Sim.Raycast.body_record(i, x, y, r)
        {xs, ys} = {Enum.map(discs, &elem(&1, 1)), Enum.map(discs, &elem(&1, 2))}

        assert Sim.Raycast.records_box(bin) ==
                 {Enum.min(xs), Enum.min(ys), Enum.max(xs), Enum.max(ys)}

        {ax, ay} = {10 * :rand.uniform(), 10 * :rand.uniform()}
        {bx, by} = {ax + 8 * :rand.uniform(), ay + 8 * :rand.uniform()}

        expected =
          for {i, x, y, r} <- discs,
              x + r >= ax and x - r <= bx and y + r >= ay and y - r <= by,
              into: <<>>,
              do: Sim.Raycast.body_record(i, x, y, r)

        assert Sim.Raycast.records_within(bin, ax, ay, bx, by) == expected
      end

      assert Sim.Raycast.records_box(<<>>) == nil

      assert_raise ArgumentError, fn ->
        Sim.Raycast.records_within(<<1, 2>>, 0.0, 0.0, 1.0, 1.0)
      end
    end

    test "strips: borders cut the width evenly; a point's strip counts the borders it passed" do
      assert Ghosts.even_borders({0.0, 30.0}, 3) == [10.0, 20.0]
      assert Ghosts.even_borders({0.0, 30.0}, 1) == []
      assert Ghosts.strip([10.0, 20.0], 5.0) == 0
      assert Ghosts.strip([10.0, 20.0], 10.0) == 1
      assert Ghosts.strip([10.0, 20.0], 25.0) == 2
    end
  end

  describe "bad options" do
    test "nodes and borders are checked, and a node that cannot be reached is named" do
      Process.flag(:trap_exit, true)
      world = [walls: T.box(4, 4)]

      assert {:error, "ThinkingCap.Sim: nodes: " <> _} =
               Sim.start(world: %ThinkingCap.Config.WDF{name: "x"}, nodes: "a@b")

      assert {:error, "ThinkingCap.Sim: borders: [5.0, 1.0] is not 2 ascending" <> _} =
               Sim.start(
                 world: %ThinkingCap.Config.WDF{name: "x", walls: world[:walls]},
                 nodes: [:a@h, :b@h, :c@h],
                 borders: [5.0, 1.0]
               )

      assert {:error, "ThinkingCap.Sim: node :nowhere@nohost cannot be reached" <> _} =
               Sim.start(
                 world: %ThinkingCap.Config.WDF{name: "x", walls: world[:walls]},
                 nodes: [node(), :nowhere@nohost]
               )
    end
  end

  # The hall run: west and east parked, the mover driving east at
  # 0.5 m/s for 22 s; samples every 2 s of its pose, odometry, laser and
  # node. `start` starts the simulation, `call` calls where it runs.
  defp run_hall(ctx, start, call, sim_opts) do
    {:ok, sim} =
      start.(
        [world: ctx.wdf, mode: :fast, running: false, step: 0.1, seed: 5, shards: 1] ++
          sim_opts
      )

    try do
      add = fn id, at, command ->
        :ok =
          call.(Sim, :add_robot, [
            sim,
            id,
            [description: ctx.robot, at: at, controller: {Cruise, [command: command]}]
          ])
      end

      add.(:mover, {2.0, 2.0, 0.0}, {:velocity, 0.5, 0.0})
      add.(:west, {4.0, 3.2, 0.0}, :stop)
      add.(:east, {15.0, 2.0, 0.0}, :stop)

      {samples, placements} =
        Enum.reduce(1..11, {[], [call.(Sim, :placement, [sim])]}, fn _, {samples, placements} ->
          :ok = call.(Sim, :run_for, [sim, 2.0])
          placement = call.(Sim, :placement, [sim])
          {:ok, pose} = call.(Sim, :pose, [sim, :mover])
          {:ok, odom} = call.(Sim, :odometry, [sim, :mover])
          {:ok, c} = call.(Sim, :controller_state, [sim, :mover])

          sample = %{
            pose: pose,
            odom: odom,
            laser: c.readings.laser.ranges,
            placement: placement.mover
          }

          {[sample | samples], [placement | placements]}
        end)

      %{
        samples: Enum.reverse(samples),
        placements: Enum.reverse(placements),
        status: call.(Sim, :status, [sim])
      }
    after
      call.(GenServer, :stop, [sim])
    end
  end
end
