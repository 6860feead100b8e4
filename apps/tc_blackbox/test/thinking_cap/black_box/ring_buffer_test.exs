defmodule ThinkingCap.BlackBox.RingBufferTest do
  use ExUnit.Case, async: true

  import ExUnit.CaptureIO

  alias ThinkingCap.{BlackBox, Blackboard}
  alias ThinkingCap.BlackBox.RingBuffer
  alias ThinkingCap.BlackBox.Test.Topics
  alias ThinkingCap.MCAP.Reader
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :tmp_dir

  # a robot of the test's own; its tuples leave the blackboard with the
  # test (the apps' tests share one VM, and later ones count maps)
  defp robot do
    robot = :"bb#{System.unique_integer([:positive])}"
    on_exit(fn -> drain({:_, robot, :_}) end)
    robot
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  defp scan(i), do: %{ranges: [1.0, 2.0, 3.0], angle_min: -0.5, angle_max: 0.5, stamp: i * 0.1}

  defp keep(robot, dir, opts \\ []) do
    {:ok, _ref} = Blackboard.subscribe(Tuples.black_box_dump(robot))
    {:ok, pid} = BlackBox.keep(robot, Keyword.merge([dir: dir, after: 0.2], opts))
    on_exit(fn -> BlackBox.forget(robot) end)
    pid
  end

  defp publish(robot, range) do
    for i <- range do
      Blackboard.out(Tuples.reading(:laser, robot, scan(i)))
      Blackboard.out(Tuples.pose(robot, %{pose: {i * 0.1, 0.0, 0.0}, stamp: i * 0.1}))
    end
  end

  # the ring buffer has taken in `n` tuples since it started
  defp await_count(pid, n, tries \\ 300) do
    info = RingBuffer.info(pid)

    cond do
      info.messages + info.dropped >= n -> info
      tries == 0 -> flunk("the ring buffer holds #{inspect(info)}, not #{n} tuples")
      true -> Process.sleep(10) && await_count(pid, n, tries - 1)
    end
  end

  defp await_dump(robot) do
    assert_receive {:blackboard, _, Tuples.black_box_dump(^robot, dump)}, 10_000
    dump
  end

  defp topics(mcap), do: Map.new(mcap.channels, fn {id, c} -> {id, c.topic} end)

  test "an E-stop dumps what came before it, read back by the MCAP reader", %{tmp_dir: dir} do
    robot = robot()
    pid = keep(robot, dir)
    publish(robot, 1..20)
    await_count(pid, 40)

    {estop, opts} = Tuples.keyed(Tuples.estop_engaged(robot, :test))
    Blackboard.out(estop, opts)
    dump = await_dump(robot)

    assert dump.reason == "estop" and dump.reasons == ["estop"]
    assert dump.to - dump.from == 60_200
    assert Path.dirname(dump.path) == dir
    assert Path.basename(dump.path) =~ ~r/^#{robot}_\d{8}T\d{6}\.\d{3}Z_estop\.mcap$/
    # 20 scans, 20 poses and their transforms, the E-stop
    assert dump.messages >= 61

    assert {:ok, mcap} = Reader.read(dump.path)
    assert mcap.mode == :indexed and mcap.data_crc == :valid
    t = topics(mcap)
    counts = Enum.frequencies_by(mcap.messages, &t[&1.channel_id])
    assert counts["/#{robot}/laser"] == 20 and counts["/#{robot}/pose"] == 20
    assert counts["/#{robot}/estop"] == 1

    # the recorder's schemas, and the scans received before the E-stop
    schema = fn topic ->
      {_, c} = Enum.find(mcap.channels, fn {_, c} -> c.topic == topic end)
      mcap.schemas[c.schema_id].name
    end

    assert schema.("/#{robot}/laser") == "foxglove.LaserScan"
    assert schema.("/#{robot}/pose") == "foxglove.PoseInFrame"
    stop = Enum.find(mcap.messages, &(t[&1.channel_id] == "/#{robot}/estop"))
    scans = Enum.filter(mcap.messages, &(t[&1.channel_id] == "/#{robot}/laser"))
    assert Enum.all?(scans, &(&1.log_time <= stop.log_time))

    # released and engaged again: a new edge, a new dump
    Blackboard.out(Tuples.estop_released(robot, :test))
    Blackboard.out(Tuples.estop_engaged(robot, :test))
    assert await_dump(robot).reason == "estop"
    assert RingBuffer.info(pid).dumps == 2
  end

  test "on request: dump/3 answers the file, the console asks through the blackboard, dumps/1 lists",
       %{tmp_dir: dir} do
    robot = robot()
    pid = keep(robot, dir)
    publish(robot, 1..5)
    await_count(pid, 10)

    assert {:ok, path} = BlackBox.dump(robot, "operator saw it")
    assert Path.basename(path) =~ ~r/_operator_saw_it\.mcap$/
    assert await_dump(robot).path == path
    assert {:ok, %{messages: [_ | _]}} = Reader.read(path)

    assert capture_io(fn -> ThinkingCap.Console.dump(robot) end) =~ "dump requested"
    from_console = await_dump(robot)
    assert from_console.reason == "console"

    assert [newest, oldest] = BlackBox.dumps(robot)
    assert newest.path == from_console.path and oldest.path == path
    assert oldest.reason == "operator_saw_it" and oldest.bytes > 0
    assert %DateTime{} = oldest.time
    assert BlackBox.dump(:nobody_keeps_this, "x") == {:error, :not_keeping}
  end

  test "dump_file/3 finds a listed dump by its name and refuses anything else",
       %{tmp_dir: dir} do
    robot = robot()
    keep(robot, dir)
    publish(robot, 1..3)
    {:ok, path} = BlackBox.dump(robot, "asked")
    name = Path.basename(path)

    assert {:ok, %{path: ^path, reason: "asked"}} = BlackBox.dump_file(robot, name)

    # a file beside the dumps that is not one, and paths out of the directory
    File.write!(Path.join(dir, "#{robot}_notes.mcap"), "x")

    assert {:error, "no dump \"#{robot}_notes.mcap\" of #{robot}"} ==
             BlackBox.dump_file(robot, "#{robot}_notes.mcap")

    for bad <- ["../#{name}", "/etc/passwd", "#{dir}/#{name}", ".hidden.mcap", "x.txt", ""] do
      assert {:error, message} = BlackBox.dump_file(robot, bad)
      assert message =~ "a dump's name is a file name such as #{robot}_"
    end

    # another robot's dump is not this one's
    assert {:error, "no dump " <> _} = BlackBox.dump_file(:"#{robot}x", name, dir: dir)
    assert {:error, "a dump's name is a string, not 42" <> _} = BlackBox.dump_file(robot, 42)
  end

  test "a snapshot copies what is held, of the tags asked for",
       %{tmp_dir: dir} do
    robot = robot()
    pid = keep(robot, dir)
    publish(robot, 1..10)
    await_count(pid, 20)

    assert {:ok, all} = BlackBox.snapshot(robot)
    assert length(all.entries) == 20 and all.robot == robot and all.dropped == 0
    assert all.from <= all.to
    assert Enum.all?(all.entries, fn {t, _} -> t >= all.from and t <= all.to end)
    times = Enum.map(all.entries, &elem(&1, 0))
    assert times == Enum.sort(times)

    assert {:ok, poses} = BlackBox.snapshot(robot, tags: [:pose])
    assert length(poses.entries) == 10

    assert Enum.map(poses.entries, fn {_, Tuples.pose(^robot, p)} -> elem(p.pose, 0) end) ==
             Enum.map(1..10, &(&1 * 0.1))

    # the buffer goes on: a later snapshot holds what came since
    publish(robot, 11..12)
    await_count(pid, 24)
    assert {:ok, %{entries: more}} = BlackBox.snapshot(robot, tags: [:pose])
    assert length(more) == 12
    assert BlackBox.snapshot(:nobody_keeps_this) == {:error, :not_keeping}
  end

  test "a snapshot lists the incidents of its span, oldest first, when and why",
       %{tmp_dir: dir} do
    robot = robot()
    keep(robot, dir, seconds: 1)
    publish(robot, 1..3)
    {estop, opts} = Tuples.keyed(Tuples.estop_engaged(robot, :test))
    Blackboard.out(estop, opts)
    assert await_dump(robot).reason == "estop"
    {:ok, path} = BlackBox.dump(robot, :operator)
    assert File.exists?(path)

    assert {:ok, snap} = BlackBox.snapshot(robot)
    assert [%{reason: "estop", at: t1}, %{reason: "operator", at: t2}] = snap.incidents
    assert t1 <= t2 and t1 >= snap.from and t2 <= snap.to

    # an incident older than what the buffer keeps is let go with it (a
    # tuple published here reaches the buffer before this test's call)
    Process.sleep(1_100)
    publish(robot, 4..5)
    assert {:ok, %{incidents: []}} = BlackBox.snapshot(robot)
  end

  test "triggers that come while a dump waits join it", %{tmp_dir: dir} do
    robot = robot()
    pid = keep(robot, dir, after: 2)
    publish(robot, 1..5)
    await_count(pid, 10)

    Blackboard.out(Tuples.estop_engaged(robot, :test))
    Blackboard.out(Tuples.pose(robot, %{pose: {0.0, 0.0, 0.0}, status: :lost, stamp: 1.0}))
    Blackboard.out(Tuples.module_gave_up(robot, %{module: :control, layer: :reactive}))
    # lost again while lost: no new trigger
    Blackboard.out(Tuples.pose(robot, %{pose: {0.0, 0.0, 0.0}, status: :lost, stamp: 1.1}))
    await_count(pid, 14)

    assert %{reasons: ["estop", "localization_lost", "module_gave_up"]} =
             RingBuffer.info(pid).pending

    dump = await_dump(robot)
    assert dump.reasons == ["estop", "localization_lost", "module_gave_up"]
    refute_receive {:blackboard, _, Tuples.black_box_dump(^robot, _)}, 300
    assert [_one] = BlackBox.dumps(robot)
  end

  test "a streak of deadline misses of the robot's activities", %{tmp_dir: dir} do
    robot = robot()
    activity = :"ctl_#{robot}"
    pid = keep(robot, dir, activities: [activity], misses: 5)

    timing = fn name, fallbacks ->
      Blackboard.out(Tuples.timing(name, %{fallbacks: fallbacks}))
    end

    # another robot's activity, and a streak broken by a summary without a miss
    timing.(:someone_elses, 100)
    timing.(activity, 2)
    timing.(activity, 4)
    timing.(activity, 4)
    timing.(activity, 6)
    timing.(activity, 8)
    await_count(pid, 5)
    refute RingBuffer.info(pid).pending
    timing.(activity, 9)
    assert await_dump(robot).reason == "deadline_misses"
  end

  test "a flood keeps to the bounds, the oldest dropped and counted", %{tmp_dir: dir} do
    robot = robot()
    pid = keep(robot, dir, max_messages: 100, max_bytes: 65_536)

    # in batches, so that the subscription's own queue never overflows
    for batch <- 0..5 do
      for i <- (batch * 500 + 1)..(batch * 500 + 500) do
        Blackboard.out(
          Tuples.reading(:laser, robot, %{scan(i) | ranges: List.duplicate(1.0, 50)})
        )
      end

      await_count(pid, batch * 500 + 500)
    end

    info = RingBuffer.info(pid)
    assert info.messages <= 100 and info.bytes <= 65_536
    assert info.dropped >= 2_900

    {:ok, path} = BlackBox.dump(robot, :flood)
    {:ok, mcap} = Reader.read(path)
    assert length(Topics.messages(mcap, "json")) <= 101
    assert length(Topics.messages(mcap, "etf")) == length(Topics.messages(mcap, "json"))
    # the newest kept: the last scan is there
    assert Enum.any?(mcap.messages, &(&1.publish_time == round(3_000 * 0.1 * 1.0e9)))
  end

  test "options are checked before anything starts", %{tmp_dir: dir} do
    assert {:error, message} = BlackBox.keep(:bb_bad, dir: dir, secnds: 3, after: -1)
    assert message =~ "unknown key :secnds in black_box; did you mean :seconds?"
    assert message =~ "black_box.after: expected a number from 0 to 600"
    assert BlackBox.ring_buffer(:bb_bad) == nil
    assert BlackBox.forget(:bb_bad) == {:error, :not_keeping}

    robot = robot()
    keep(robot, dir)
    assert BlackBox.keep(robot, dir: dir) == {:error, :already_keeping}
    assert robot not in BlackBox.recording()
  end
end
