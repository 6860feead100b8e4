defmodule ThinkingCap.Robot.Create2EndToEndTest do
  # The Create 2 driver started by the runtime from an ADF, against the
  # emulator on a pty: hosts modules in this node's runtime, not beside
  # other tests.
  use ExUnit.Case, async: false

  import ThinkingCap.Robot.Test.Eventually

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.Testing.Create2Emulator, as: Emulator

  @moduletag :tmp_dir
  @rdf Path.expand("../../../../../priv/examples/create2.rdf", __DIR__)

  setup %{tmp_dir: dir} do
    link = Path.join(dir, "create2")
    emu = start_supervised!({Emulator, link: link})
    %{emu: emu, link: link, dir: dir}
  end

  defp start(dir, module, params) do
    robot = :"c#{System.unique_integer([:positive])}"
    base = :"base_#{robot}"
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: #{inspect(@rdf)},
      modules: [
        #{base}: [module: #{inspect(module)}, activity: :periodic, period: 0.01,
                  deadline: 0.005, fallback: :stop, params: #{inspect(params)}]
      ]
    ]
    """)

    adf = Config.read!(path)

    # the module ends with its test, for good: a copy left running (its
    # supervisor restarting it as it was stopped) kept opening its device
    # path, and its wire its fallback, into a later test's pty
    on_exit(fn ->
      assert Runtime.stop(base) in [:ok, {:error, :not_running}]
      assert Runtime.whereis(base) == nil
      refute Map.has_key?(ThinkingCap.Cycle.timing(), base)
    end)

    {:ok, _} = Runtime.start(adf)
    {robot, base}
  end

  defp start_create2(%{dir: dir, link: link}, params \\ []) do
    {robot, base} =
      start(
        dir,
        ThinkingCap.Robot.Create2,
        [device: link, command_timeout: 30.0, reconnect_every: 0.1] ++ params
      )

    eventually(fn ->
      assert %{connected: true, mode: :safe, streaming: true} = latest(:link, robot)
    end)

    eventually(fn -> assert %{pose: _} = latest(:odometry, robot) end)
    {robot, base}
  end

  defp drive(robot, command),
    do: Blackboard.out({:drive, robot, %{command: command}}, key: {:drive, robot})

  defp latest(tag, robot) do
    case Blackboard.rdp({tag, robot, :_}) do
      {:ok, {^tag, ^robot, payload}} -> payload
      _ -> nil
    end
  end

  # stops the robot, then the odometry on the blackboard must be where the
  # emulator is
  defp assert_odometry_matches(robot, emu) do
    drive(robot, :stop)
    eventually(fn -> assert %{left: 0, right: 0} = Emulator.state(emu) end)

    eventually(fn ->
      %{pose: {ex, ey, et}} = Emulator.state(emu)
      %{pose: {ox, oy, ot}} = latest(:odometry, robot)
      assert_in_delta ox, ex, 0.005
      assert_in_delta oy, ey, 0.005
      assert_in_delta ot, et, 0.02
    end)
  end

  test "drive tuples turn the emulator's wheels; odometry follows its pose; stopping the module stops it",
       %{emu: emu} = ctx do
    {robot, base} = start_create2(ctx)

    assert {:ok, {:robot, ^robot, %{drive: :differential}}} =
             Blackboard.rd({:robot, robot, :_}, 1000)

    drive(robot, {:velocity, 0.2, 0.0})
    eventually(fn -> assert %{mode: :safe, left: 200, right: 200} = Emulator.state(emu) end)

    assert Enum.any?(
             Emulator.commands(emu),
             &match?(%{command: {:drive_direct, 200, 200}, applied: true}, &1)
           )

    Process.sleep(500)
    %{pose: {x, y, _}} = Emulator.state(emu)
    assert x > 0.05
    assert_in_delta y, 0.0, 0.001
    eventually(fn -> assert latest(:odometry, robot).v > 0.1 end)
    assert_odometry_matches(robot, emu)

    # turning in place: opposite wheel speeds (omega b / 2 = 117.5 mm/s)
    drive(robot, {:velocity, 0.0, 1.0})
    eventually(fn -> assert %{left: -118, right: 118} = Emulator.state(emu) end)
    Process.sleep(700)
    assert %{pose: {_, _, theta}} = Emulator.state(emu)
    assert theta > 0.4
    assert_odometry_matches(robot, emu)

    # stopped by the module's end, the OI stopped
    drive(robot, {:velocity, 0.1, 0.0})
    eventually(fn -> assert %{left: 100, right: 100} = Emulator.state(emu) end)
    :ok = Runtime.stop(base)

    eventually(fn ->
      assert %{left: 0, right: 0, mode: :off, streaming?: false} = Emulator.state(emu)
    end)
  end

  test "the bumper and the battery reach the blackboard", %{emu: emu} = ctx do
    {robot, _base} = start_create2(ctx)
    eventually(fn -> assert %{pressed: false} = latest(:bumper, robot) end)

    Emulator.bump(emu, :left)

    eventually(fn ->
      assert %{pressed: true, left: true, right: false} = latest(:bumper, robot)
    end)

    Emulator.bump(emu, :none)
    eventually(fn -> assert %{pressed: false, left: false} = latest(:bumper, robot) end)

    eventually(fn ->
      assert %{voltage: v, charge: c, capacity: cap, percent: p} = latest(:battery, robot)
      assert_in_delta v, 15.6, 0.001
      assert_in_delta c, 2.4, 0.001
      assert_in_delta cap, 3.0, 0.001
      assert_in_delta p, 80.0, 0.01
    end)

    # a wheel drop in Safe mode: the robot stops and goes Passive, the driver says so
    drive(robot, {:velocity, 0.1, 0.0})
    eventually(fn -> assert %{left: 100} = Emulator.state(emu) end)
    Emulator.wheel_drop(emu, true)
    eventually(fn -> assert %{wheel_drop: true} = latest(:bumper, robot) end)
    eventually(fn -> assert %{mode: :passive} = latest(:link, robot) end)
    assert %{left: 0, right: 0} = Emulator.state(emu)

    # the wheels back on the floor: the next command re-enters Safe mode
    Emulator.wheel_drop(emu, false)
    eventually(fn -> assert %{wheel_drop: false} = latest(:bumper, robot) end)
    drive(robot, {:velocity, 0.12, 0.0})
    eventually(fn -> assert %{mode: :safe, left: 120, right: 120} = Emulator.state(emu) end)
  end

  test "a storm of random bytes on the line: nothing crashes, the stream goes on",
       %{emu: emu} = ctx do
    {robot, base} = start_create2(ctx)
    pid = Runtime.whereis(base)
    drive(robot, {:velocity, 0.1, -0.2})
    eventually(fn -> assert %{left: 124, right: 77} = Emulator.state(emu) end)

    for _ <- 1..50 do
      Emulator.garbage(emu, :crypto.strong_rand_bytes(:rand.uniform(64)))
      Process.sleep(:rand.uniform(20))
    end

    %{frames: f} = latest(:link, robot)

    eventually(fn ->
      assert %{connected: true, streaming: true, frames: f2, garbage_bytes: g} =
               latest(:link, robot)

      assert f2 > f + 10
      assert g > 0
    end)

    assert_odometry_matches(robot, emu)
    assert Runtime.whereis(base) == pid
  end

  test "corrupted and truncated frames and garbage are rejected and counted; odometry stays right",
       %{emu: emu} = ctx do
    {robot, base} = start_create2(ctx)
    pid = Runtime.whereis(base)
    drive(robot, {:velocity, 0.15, 0.3})

    eventually(fn ->
      %{left: l, right: r} = Emulator.state(emu)
      assert l > 0 and r > l
    end)

    Emulator.corrupt(emu, 5)
    Process.sleep(200)
    Emulator.truncate(emu, 5)
    Process.sleep(200)
    Emulator.garbage(emu, <<19, 28, 7, 0, 1, 2, 3, 255, 19>>)
    Emulator.garbage(emu, :crypto.strong_rand_bytes(100))

    eventually(fn ->
      assert %{connected: true, rejected: rejected, garbage_bytes: g, frames: f} =
               latest(:link, robot)

      assert rejected >= 10
      assert g > 0
      assert f > 20
    end)

    assert_odometry_matches(robot, emu)
    assert Runtime.whereis(base) == pid
  end

  test "the line unplugged: reported lost, reconnected when it is back, streaming again",
       %{emu: emu} = ctx do
    {robot, base} = start_create2(ctx)
    pid = Runtime.whereis(base)
    :ok = ThinkingCap.Cycle.subscribe(base)

    :ok = Emulator.unplug(emu)
    eventually(fn -> assert %{connected: false, streaming: false} = latest(:link, robot) end)
    Process.sleep(300)

    :ok = Emulator.replug(emu)

    eventually(fn ->
      assert %{connected: true, streaming: true, mode: :safe} = latest(:link, robot)
    end)

    %{stamp: s1} = latest(:odometry, robot)
    eventually(fn -> assert latest(:odometry, robot).stamp > s1 end)

    # and it drives again, the timing worker writing on the new line: the
    # driver hands it over (the worker reopens no other device by itself)
    drive(robot, {:velocity, 0.1, 0.0})
    eventually(fn -> assert %{left: 100, right: 100} = Emulator.state(emu) end)

    ThinkingCap.Testing.Cycle.applied_until(
      base,
      &(&1.kind == :fresh and &1.wired and &1.command == {:velocity, 0.1, 0.0})
    )

    assert_odometry_matches(robot, emu)
    assert Runtime.whereis(base) == pid
  end

  test "the timing worker owns the line: a killed base module's robot gets Drive Direct 0 0 at once",
       %{emu: emu} = ctx do
    {robot, base} = start_create2(ctx)
    drive(robot, {:velocity, 0.2, 0.0})
    eventually(fn -> assert %{left: 200, right: 200} = Emulator.state(emu) end)

    # every cycle's Drive Direct goes on the line, written by the worker
    # (how many in 100 ms is the timing benchmark's business)
    before = length(Emulator.commands(emu))
    eventually(fn -> assert length(Emulator.commands(emu)) - before >= 5 end)

    killed_at = System.monotonic_time()
    Process.exit(Runtime.whereis(base), :kill)

    # the worker writes the stop as soon as it hears of the death: before
    # it, at most the result the module sent before it died (the worker
    # may apply it after the kill), and nothing of the restarted module
    eventually(fn ->
      after_kill = Enum.filter(Emulator.commands(emu), &(&1.at > killed_at))

      {before_stop, [_stop | _]} =
        Enum.split_while(after_kill, &(&1.command != {:drive_direct, 0, 0}))

      assert length(before_stop) <= 1
    end)
  end

  test "the same ADF with the test robot runs without hardware", %{dir: dir} do
    {robot, _base} = start(dir, ThinkingCap.Testing.Robot, command_timeout: 30.0)

    assert {:ok, {:robot, ^robot, %{name: "irobot-create2"}}} =
             Blackboard.rd({:robot, robot, :_}, 1000)

    drive(robot, {:velocity, 0.2, 0.0})

    eventually(fn ->
      assert {:ok, {:driven, ^robot, %{command: {:velocity, 0.2, 0.0}}}} =
               Blackboard.rdp({:driven, robot, :_})
    end)
  end
end
