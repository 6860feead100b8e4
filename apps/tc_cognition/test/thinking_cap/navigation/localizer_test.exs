defmodule ThinkingCap.Navigation.LocalizerTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{EKF, Localizer}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  @rdf Path.expand("../../../../../priv/examples/office_robot.rdf", __DIR__)

  @wdf """
  [
    name: "beacon box",
    walls: [{{0, 0}, {10, 0}}, {{10, 0}, {10, 8}}, {{10, 8}, {0, 8}}, {{0, 8}, {0, 0}}],
    beacons: [
      [name: :n1, at: {0.5, 0.5}],
      [name: :n2, at: {9.5, 0.5}],
      [name: :n3, at: {9.5, 7.5}],
      [name: :n4, at: {0.5, 7.5}]
    ],
    waypoints: [[name: :start, at: {2.0, 3.0, 1.5707963}], [name: :flat, at: {4.0, 4.0}]]
  ]
  """

  @beacons %{n1: {0.5, 0.5}, n2: {9.5, 0.5}, n3: {9.5, 7.5}, n4: {0.5, 7.5}}

  setup %{tmp_dir: dir} do
    path = Path.join(dir, "box.wdf")
    File.write!(path, @wdf)
    context = %{name: :localizer, robot: :r1, node: node(), activity: :event, rdf: nil, wdf: path}
    %{context: context}
  end

  defp outs(actions), do: for({:out, {tuple, opts}} <- actions, do: {tuple, opts})

  defp odom(pose, t), do: {:odom, :r1, %{pose: pose, twist: {0.0, 0.0}, stamp: t}}

  defp detections(truth, ids \\ Map.keys(@beacons)) do
    for id <- ids do
      {r, b} = EKF.measure(truth, @beacons[id])
      %{id: id, range: r, bearing: b}
    end
  end

  @moduletag :tmp_dir

  test "subscribes to its robot's odometry and beacons, starts at a waypoint", %{context: ctx} do
    {actions, state} = Localizer.init([initial: :start, odometry: :wheels], ctx)
    assert {:subscribe, {:wheels, :r1, :_}} in actions
    assert {:subscribe, {:beacons, :r1, :_}} in actions

    {actions, _state} =
      Localizer.handle_tuple({:wheels, :r1, %{pose: {5.0, 5.0, 2.0}, stamp: 0.0}}, state)

    assert [{{:pose, :r1, payload}, [key: {:pose, :r1}]}] = outs(actions)
    assert payload.pose == {2.0, 3.0, 1.5707963}
    assert payload.stamp == 0.0
    assert payload.beacons_used == 0
    assert [[a, 0.0, 0.0], [0.0, b, 0.0], [0.0, 0.0, c]] = payload.covariance
    assert_in_delta a, 0.01, 1.0e-12
    assert_in_delta b, 0.01, 1.0e-12
    assert_in_delta c, 0.0025, 1.0e-12

    # a waypoint without heading faces θ = 0
    {_, state} = Localizer.init([initial: :flat], ctx)
    assert state.ekf.pose == {4.0, 4.0, 0.0}
  end

  test "listens to the odometry sensor its robot's RDF names", %{context: ctx} do
    create2 = Path.expand("../../../../../priv/examples/create2.rdf", __DIR__)
    {actions, _} = Localizer.init([initial: :start], %{ctx | rdf: create2})
    assert {:subscribe, {:odometry, :r1, :_}} in actions
    {actions, _} = Localizer.init([initial: :start], %{ctx | rdf: @rdf})
    assert {:subscribe, {:odom, :r1, :_}} in actions
  end

  test "odometry moves the pose from the initial one, publishing at most every 0.1 s",
       %{context: ctx} do
    {_, state} = Localizer.init([initial: :start], ctx)

    # the odometry frame starts elsewhere: only the relative motion counts
    {published, state} =
      Enum.flat_map_reduce(0..50, state, fn i, state ->
        {actions, state} =
          Localizer.handle_tuple(odom({-1.0 + i * 0.02, 0.0, 0.0}, i * 0.02), state)

        {outs(actions), state}
      end)

    # 1 s of odometry at 50 Hz: a publication every 5 readings
    assert length(published) == 11
    {{:pose, :r1, last}, _} = List.last(published)
    {x, y, th} = last.pose
    # facing +y at the start: one metre forward is one metre up
    assert_in_delta x, 2.0, 1.0e-6
    assert_in_delta y, 4.0, 1.0e-6
    assert_in_delta th, 1.5707963, 1.0e-6
    assert last.stamp == 1.0
    [[sxx, _, _], [_, syy, _], _] = last.covariance
    assert sxx > 0.01 and syy > 0.01

    # other robots' tuples are ignored
    assert {[], ^state} = Localizer.handle_tuple({:odom, :r2, %{pose: {9.0, 9.0, 0.0}}}, state)
  end

  test "after a failover it resumes from the handoff and the motion since", %{context: ctx} do
    {_, state} = Localizer.init([initial: :start], ctx)
    {_, state} = Localizer.handle_tuple(odom({-1.0, 0.0, 0.0}, 0.0), state)
    {_, state} = Localizer.handle_tuple(odom({-0.5, 0.0, 0.0}, 0.5), state)
    handoff = Localizer.handoff(state)

    # a new instance elsewhere (initial :start again) gets the handoff; the
    # robot has moved another half metre meanwhile
    {_, resumed} = Localizer.init([initial: :start], Map.put(ctx, :handoff, handoff))
    {actions, _} = Localizer.handle_tuple(odom({0.0, 0.0, 0.0}, 1.0), resumed)
    [{{:pose, :r1, %{pose: {x, y, _}}}, _}] = outs(actions)
    assert_in_delta x, 2.0, 1.0e-6
    assert_in_delta y, 4.0, 1.0e-6

    # without one, from the initial pose
    {_, fresh} = Localizer.init([initial: :start], Map.put(ctx, :handoff, nil))
    {actions, _} = Localizer.handle_tuple(odom({0.0, 0.0, 0.0}, 1.0), fresh)
    assert [{{:pose, :r1, %{pose: {2.0, 3.0, _}}}, _}] = outs(actions)
  end

  test "beacon detections pull a wrong estimate to the truth", %{context: ctx} do
    truth = {2.3, 2.8, 1.4}
    {_, state} = Localizer.init([initial: :start, initial_sigma: {0.5, 0.3}], ctx)
    {_, state} = Localizer.handle_tuple(odom({0.0, 0.0, 0.0}, 0.0), state)

    {actions, state} =
      Localizer.handle_tuple({:beacons, :r1, %{detections: detections(truth), stamp: 0.2}}, state)

    assert [{{:pose, :r1, payload}, [key: {:pose, :r1}]}] = outs(actions)
    assert payload.beacons_used == 4
    assert payload.stamp == 0.2
    {x, y, th} = payload.pose
    assert_in_delta x, 2.3, 0.02
    assert_in_delta y, 2.8, 0.02
    assert_in_delta th, 1.4, 0.02
    [[sxx, _, _], _, _] = payload.covariance
    assert sxx < 0.25 / 100

    # an impossible detection is gated out; unknown beacons are ignored
    bad = [%{id: :n1, range: 30.0, bearing: 0.0}, %{id: :elsewhere, range: 1.0, bearing: 0.0}]
    {actions, _} = Localizer.handle_tuple({:beacons, :r1, %{detections: bad, stamp: 0.4}}, state)
    pose = payload.pose
    assert [{{:pose, :r1, %{beacons_used: 0, pose: ^pose}}, _}] = outs(actions)
  end

  # 5 s of driving an arc with slipping odometry at 50 Hz, beacons at 5 Hz;
  # the last publication and the true pose
  defp drive(state, seed) do
    rng = :rand.seed_s(:exsss, seed)
    acc = {state, {2.0, 2.0, 0.0}, {0.0, 0.0, 0.0}, rng, nil}

    {state, truth, _odom, _rng, last} =
      Enum.reduce(1..250, acc, fn i, {state, truth, odom, rng, last} ->
        t = i * 0.02
        delta = {0.3 * 0.02, 0.0, 0.2 * 0.02}
        truth = EKF.motion(truth, delta)
        {n, rng} = :rand.normal_s(rng)
        odom = EKF.motion(odom, {0.3 * 0.02 * (1 + 0.05 * n), 0.0, 0.2 * 0.02})
        {a1, state} = Localizer.handle_tuple(odom(odom, t), state)

        {a2, state, rng} =
          if rem(i, 10) == 0 do
            {ds, rng} =
              Enum.map_reduce(detections(truth), rng, fn d, rng ->
                {nr, rng} = :rand.normal_s(rng)
                {nb, rng} = :rand.normal_s(rng)
                {%{d | range: d.range + 0.02 * nr, bearing: d.bearing + 0.02 * nb}, rng}
              end)

            {a, s} = Localizer.handle_tuple({:beacons, :r1, %{detections: ds, stamp: t}}, state)
            {a, s, rng}
          else
            {[], state, rng}
          end

        last =
          case outs(a1 ++ a2) do
            [] -> last
            outs -> outs |> List.last() |> elem(0) |> elem(2)
          end

        {state, truth, odom, rng, last}
      end)

    {state, truth, last}
  end

  defp error(%{pose: {x, y, th}}, {tx, ty, tth}),
    do: {:math.sqrt((x - tx) ** 2 + (y - ty) ** 2), abs(normalize_angle(th - tth))}

  test "tracks a drive with noisy odometry from a doubtful start, defaults from the RDF",
       %{context: ctx} do
    # truth starts at {2, 2, 0}
    params = [initial: {2.5, 2.5, 0.2}, initial_sigma: {1.0, 0.5}]
    {_, state} = Localizer.init(params, %{ctx | rdf: @rdf})
    # the RDF's odometry error and beacon sensor noise
    assert state.motion_noise == %{slip: 0.01, turn_slip: 0.02}
    assert state.sensor_noise == {0.02, 0.02}

    {state, truth, last} = drive(state, 11)
    {dxy, dth} = error(last, truth)
    assert dxy < 0.05
    assert dth < 0.03
    assert last.beacons_used == 4
    assert state.ekf.pose == last.pose
  end

  test "a filter started too confident of a wrong pose finds itself again", %{context: ctx} do
    # σ 0.1 m, 0.05 rad but 0.7 m and 0.2 rad off: every detection is gated out at first
    {_, state} = Localizer.init([initial: {2.5, 2.5, 0.2}], ctx)
    {_, _, last} = drive(state, 5)
    {dxy, dth} = error(last, truth = {2.0, 2.0, 0.0} |> drive_truth())
    assert dxy < 0.05 and dth < 0.03

    # without the recovery it stays lost
    {_, state} = Localizer.init([initial: {2.5, 2.5, 0.2}, lost_after: :never], ctx)
    {_, ^truth, last} = drive(state, 5)
    {dxy, _} = error(last, truth)
    assert dxy > 0.3
    assert last.beacons_used < 4
  end

  defp drive_truth(start),
    do: Enum.reduce(1..250, start, fn _, p -> EKF.motion(p, {0.3 * 0.02, 0.0, 0.2 * 0.02}) end)

  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  defp collect(acc) do
    receive do
      {:tc_sim, :readings, :r1, readings} -> collect([readings | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  test "follows a robot of the simulator in the office" do
    {:ok, sim} = ThinkingCap.Sim.start_link(world: @office, mode: :fast, seed: 3, running: false)
    :ok = ThinkingCap.Sim.add_robot(sim, :r1, rdf: @rdf, at: {5.0, 1.5, 0.0}, owner: self())
    ThinkingCap.Sim.command(sim, :r1, {:velocity, 0.3, 0.05})
    :ok = ThinkingCap.Sim.run_for(sim, 15.0)
    steps = collect([])
    assert length(steps) > 500

    ctx = %{name: :loc, robot: :r1, node: node(), activity: :event, rdf: @rdf, wdf: @office}
    {_, state} = Localizer.init([initial: {5.3, 1.3, 0.1}, initial_sigma: {0.5, 0.2}], ctx)

    # the estimate against the simulator's true pose, every 0.1 s
    {_, errors} =
      Enum.reduce(steps, {state, []}, fn readings, {state, errors} ->
        Enum.reduce(readings, {state, errors}, fn
          {:sim_pose, %{pose: truth, stamp: t}}, {state, errors} ->
            {state, [{t, error(state.ekf, truth)} | errors]}

          {sensor, payload}, {state, errors} ->
            {_, state} = Localizer.handle_tuple({sensor, :r1, payload}, state)
            {state, errors}
        end)
      end)

    settled = for {t, e} <- errors, t >= 2.0, do: e
    assert length(settled) > 100
    assert Enum.all?(settled, fn {dxy, dth} -> dxy < 0.06 and dth < 0.03 end)
  end

  test "refuses an unknown waypoint, naming the known ones", %{context: ctx} do
    assert_raise ArgumentError, ~r/:nowhere is not a waypoint.*:start, :flat/, fn ->
      Localizer.init([initial: :nowhere], ctx)
    end
  end
end
