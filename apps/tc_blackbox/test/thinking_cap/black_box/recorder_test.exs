defmodule ThinkingCap.BlackBox.RecorderTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.{BlackBox, Blackboard}
  alias ThinkingCap.BlackBox.Recorder
  alias ThinkingCap.BlackBox.Core.Channels
  alias ThinkingCap.BlackBox.Test.{NodeReader, Topics}
  alias ThinkingCap.MCAP.Reader
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :tmp_dir

  # a robot of the test's own; its tuples leave the blackboard with the
  # test (the apps' tests share one VM, and later ones count maps)
  defp robot do
    robot = :"rec#{System.unique_integer([:positive])}"
    on_exit(fn -> drain({:_, robot, :_}) end)
    robot
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  defp scan(i),
    do: %{
      ranges: Enum.map(1..90, &(&1 * 0.05 + i * 0.001)),
      angle_min: -1.57,
      angle_max: 1.57,
      angle_increment: 3.14 / 89,
      range_min: 0.05,
      range_max: 8.0,
      stamp: i * 0.1
    }

  # laser scans, poses, one map and a command per step
  defp publish(robot, steps) do
    Blackboard.out(Tuples.map(robot, OccupancyGrid.new(40, 30, resolution: 0.1)))

    for i <- 1..steps do
      Blackboard.out(Tuples.reading(:laser, robot, scan(i)))
      Blackboard.out(Tuples.pose(robot, %{pose: {i * 0.01, 1.0, 0.1}, stamp: i * 0.1}))
      Blackboard.out(Tuples.drive(robot, %{command: {:velocity, 0.2, 0.0}}))
    end
  end

  # waits until the recorder has written `n` messages
  defp await_messages(pid, n, tries \\ 200) do
    cond do
      Recorder.info(pid).messages >= n ->
        :ok

      tries == 0 ->
        flunk("the recorder wrote #{Recorder.info(pid).messages} messages, not #{n}")

      true ->
        Process.sleep(10)
        await_messages(pid, n, tries - 1)
    end
  end

  for compression <- [:zstd, :lz4, :none] do
    test "records a robot's tuples, read back by our reader and by @mcap/core (#{compression})",
         %{tmp_dir: dir} do
      robot = robot()
      r = Atom.to_string(robot)
      {:ok, pid} = BlackBox.record(robot, dir: dir, compression: unquote(compression))
      assert BlackBox.recorder(robot) == pid
      assert robot in BlackBox.recording()

      # another robot's tuples are not recorded
      Blackboard.out(Tuples.reading(:laser, :someone_else, scan(1)))
      publish(robot, 50)
      # 1 map + 50 x (scan, pose and its transform, drive) for Foxglove,
      # and the 151 tuples whole
      await_messages(pid, 352)
      assert :ok = BlackBox.stop(robot)
      assert BlackBox.recorder(robot) == nil

      assert [file] = Path.wildcard(Path.join(dir, "*.mcap"))
      assert Path.basename(file) =~ ~r/^#{r}_\d{8}T\d{6}\.\d{3}Z\.mcap$/

      assert {:ok, mcap} = Reader.read(file)
      assert mcap.mode == :indexed and mcap.data_crc == :valid and mcap.summary_crc == :valid
      topics = Map.new(mcap.channels, fn {id, c} -> {id, c.topic} end)

      counts = Topics.counts(mcap, "json")

      assert counts == %{
               "/#{r}/laser" => 50,
               "/#{r}/pose" => 50,
               "/#{r}/tf" => 50,
               "/#{r}/drive" => 50,
               "/#{r}/map" => 1
             }

      # and each tuple whole, exactly as it was written: atoms, tuples, floats
      terms = Topics.counts(mcap, "etf")

      assert terms == %{
               "/etf/#{r}/laser" => 50,
               "/etf/#{r}/pose" => 50,
               "/etf/#{r}/drive" => 50,
               "/etf/#{r}/map" => 1
             }

      assert Topics.terms(mcap, "/etf/#{r}/laser") ==
               for(i <- 1..50, do: Tuples.reading(:laser, robot, scan(i)))

      assert [Tuples.drive(^robot, %{command: {:velocity, 0.2, 0.0}}) | _] =
               Topics.terms(mcap, "/etf/#{r}/drive")

      assert [Tuples.map(^robot, %OccupancyGrid{width: 40, height: 30})] =
               Topics.terms(mcap, "/etf/#{r}/map")

      # publish time: the stamp; log time: the receipt, on the epoch's clock
      laser = Enum.find(mcap.messages, &(topics[&1.channel_id] == "/#{r}/laser"))
      assert laser.publish_time == 100_000_000
      assert abs(laser.log_time - System.os_time(:nanosecond)) < 60_000_000_000
      json = :jiffy.decode(laser.data, [:return_maps])
      # Foxglove's ranges to the millimetre (the terms above exact)
      assert json["ranges"] == Enum.map(scan(1).ranges, &(round(&1 * 1000) / 1000))

      assert {:ok, node} = NodeReader.read(file)
      assert node["chunkIndexes"] >= 1

      assert node["compressions"] == [
               %{zstd: "zstd", lz4: "lz4", none: ""}[unquote(compression)]
             ]

      assert node["summaryCrc"] == "valid" and node["dataSectionCrc"] == "valid"
      assert node["messages"] == 352 and node["ordered"]

      assert node["schemas"] == [
               "foxglove.FrameTransform",
               "foxglove.Grid",
               "foxglove.LaserScan",
               "foxglove.PoseInFrame",
               "thinkingcap.Tuple"
             ]

      assert node["channels"]["/#{r}/laser"] == %{
               "schema" => "foxglove.LaserScan",
               "encoding" => "json",
               "count" => 50
             }

      assert node["channels"]["/#{r}/map"]["schema"] == "foxglove.Grid"
      assert node["channels"]["/#{r}/pose"]["schema"] == "foxglove.PoseInFrame"

      assert node["channels"]["/etf/#{r}/laser"] == %{
               "schema" => :null,
               "encoding" => "etf",
               "count" => 50
             }

      assert node["statistics"]["channelMessageCounts"] == Map.merge(counts, terms)
      assert node["first"]["/#{r}/map"]["column_count"] == 40
    end
  end

  test "a module's callbacks in lists are written 64 a message, in order", %{tmp_dir: dir} do
    robot = robot()
    {:ok, pid} = BlackBox.record(robot, dir: dir)
    t0 = System.monotonic_time()
    us = System.convert_time_unit(1, :microsecond, :native)
    events = for n <- 0..149, do: {n, t0 + n * 10 * us, {{:tick, n}, []}}
    {first, rest} = Enum.split(events, 100)
    send(pid, {:tc_trace_batch, robot, :m1, first})
    send(pid, {:tc_trace_batch, robot, :m1, rest})
    {:ok, _} = Recorder.rotate(pid)
    assert Recorder.info(pid).callbacks == 150
    :ok = BlackBox.stop(robot)

    messages =
      for file <- Path.wildcard(Path.join(dir, "*.mcap")),
          {:ok, mcap} = Reader.read(file),
          m <- mcap.messages,
          mcap.channels[m.channel_id].topic == "/trace/#{robot}/m1",
          do: m

    assert Enum.map(messages, & &1.sequence) == [0, 64, 128]
    decoded = Enum.map(messages, &:erlang.binary_to_term(&1.data))
    assert Enum.map(decoded, &length/1) == [64, 64, 22]

    # each callback n, 10 µs after the one before, its µs after its message's log time
    for {m, list} <- Enum.zip(messages, decoded), {n, offset, event} <- list do
      assert event == {{:tick, n}, []}
      [{first_n, 0, _} | _] = list
      assert offset == (n - first_n) * 10
      assert m.log_time == m.publish_time
    end
  end

  test "tuples and callbacks come in lists, each logged when it was delivered",
       %{tmp_dir: dir} do
    robot = robot()
    r = Atom.to_string(robot)
    {:ok, pid} = BlackBox.record(robot, dir: dir, chunk_seconds: 0.5)

    # woken once a list: a batched subscription (a quarter of a chunk),
    # its tuples held as their writers encoded them, and a batched trace sink
    assert [%{batch: %{max_batch: 256, max_delay_ms: 125, hold: {Channels, :held}}}] =
             for(s <- Blackboard.subscriptions(), s.pid == pid, do: s)

    assert ThinkingCap.Runtime.Trace.batch_sinks(robot) == [pid]
    assert ThinkingCap.Runtime.Trace.plain_sinks(robot) == []

    # each log time is its write's, not the list's arrival
    times =
      for i <- 1..3 do
        before = System.os_time(:nanosecond)
        Blackboard.out(Tuples.drive(robot, %{command: {:velocity, i * 0.1, 0.0}}))
        later = System.os_time(:nanosecond)
        Process.sleep(30)
        {before, later}
      end

    await_messages(pid, 6)
    :ok = BlackBox.stop(robot)
    assert [file] = Path.wildcard(Path.join(dir, "*.mcap"))
    assert {:ok, mcap} = Reader.read(file)
    topic = Map.new(mcap.channels, fn {id, c} -> {id, c.topic} end)
    logged = for m <- mcap.messages, topic[m.channel_id] == "/etf/#{r}/drive", do: m.log_time
    assert length(logged) == 3

    # within a few ms (the epoch's clock against the system's), where the
    # lists came 125 ms after their first tuple
    for {log_time, {before, later}} <- Enum.zip(logged, times) do
      assert log_time >= before - 5_000_000 and log_time <= later + 5_000_000
    end
  end

  test "a stop writes the tuples still held for the recorder", %{tmp_dir: dir} do
    robot = robot()
    r = Atom.to_string(robot)
    {:ok, _pid} = BlackBox.record(robot, dir: dir)
    # held for up to 100 ms before they are sent: stopped before that
    for i <- 1..5, do: Blackboard.out(Tuples.drive(robot, %{command: {:velocity, i * 0.1, 0.0}}))
    :ok = BlackBox.stop(robot)
    assert [file] = Path.wildcard(Path.join(dir, "*.mcap"))
    assert {:ok, mcap} = Reader.read(file)
    assert Topics.counts(mcap, "etf") == %{"/etf/#{r}/drive" => 5}
  end

  test "chunks are written every chunk_seconds: the open file reads up to its last chunk",
       %{tmp_dir: dir} do
    robot = robot()
    {:ok, pid} = BlackBox.record(robot, dir: dir, chunk_seconds: 0.05)
    publish(robot, 20)
    # 81 for Foxglove, 61 tuples whole
    await_messages(pid, 142)
    # a tick or two later, the chunk is on disk, the file still open
    Process.sleep(200)
    %{file: file} = Recorder.info(pid)
    assert {:ok, mcap} = Reader.read(file)
    assert mcap.mode == :linear and mcap.truncated
    assert length(mcap.messages) == 142
    :ok = BlackBox.stop(robot)
  end

  test "files rotate by size, each one whole", %{tmp_dir: dir} do
    robot = robot()

    {:ok, pid} =
      BlackBox.record(robot, dir: dir, file_bytes: 65_536, chunk_bytes: 8_192, compression: :none)

    publish(robot, 300)
    # 1201 for Foxglove, 901 tuples whole
    await_messages(pid, 2102)
    :ok = BlackBox.stop(robot)

    files = Path.wildcard(Path.join(dir, "*.mcap"))
    assert length(files) > 3

    total =
      for file <- files, reduce: 0 do
        n ->
          assert {:ok, %{mode: :indexed, data_crc: :valid} = mcap} = Reader.read(file)
          # each file declares the channels it uses
          assert Enum.all?(mcap.messages, &Map.has_key?(mcap.channels, &1.channel_id))
          n + length(mcap.messages)
      end

    assert total == 2102
  end

  test "files rotate by time", %{tmp_dir: dir} do
    robot = robot()
    {:ok, pid} = BlackBox.record(robot, dir: dir, file_seconds: 1, chunk_seconds: 0.05)
    publish(robot, 1)
    # 5 for Foxglove, 4 tuples whole
    await_messages(pid, 9)
    Process.sleep(1_300)
    assert length(Recorder.info(pid).files) >= 2
    :ok = BlackBox.stop(robot)

    assert {:ok, first} =
             dir |> Path.join("*.mcap") |> Path.wildcard() |> Enum.min() |> Reader.read()

    assert length(first.messages) == 9
  end

  test "chosen templates only", %{tmp_dir: dir} do
    robot = robot()
    {:ok, pid} = BlackBox.record(robot, dir: dir, templates: [Tuples.drive(robot)])
    publish(robot, 10)
    await_messages(pid, 20)
    :ok = BlackBox.stop(robot)
    {:ok, mcap} = dir |> Path.join("*.mcap") |> Path.wildcard() |> hd() |> Reader.read()
    topics = mcap.channels |> Enum.map(fn {_, c} -> c.topic end) |> Enum.sort()
    assert topics == ["/etf/#{robot}/drive", "/#{robot}/drive"]
    assert length(mcap.messages) == 20
  end

  test "replay: false records Foxglove's messages only, and does not replay", %{tmp_dir: dir} do
    robot = robot()
    {:ok, pid} = BlackBox.record(robot, dir: dir, replay: false)
    publish(robot, 10)
    await_messages(pid, 41)
    :ok = BlackBox.stop(robot)
    [file] = Path.wildcard(Path.join(dir, "*.mcap"))
    {:ok, mcap} = Reader.read(file)
    assert length(mcap.messages) == 41
    assert Topics.messages(mcap, "etf") == []
    assert {:error, message} = ThinkingCap.BlackBox.Replay.open(file)
    assert message =~ "no whole terms"
  end

  test "options are checked before anything starts", %{tmp_dir: dir} do
    assert {:error, message} = BlackBox.record(:r9, dir: dir, compresion: :lz4)
    assert message =~ "unknown key :compresion in recorder; did you mean :compression?"

    assert {:error, message} = BlackBox.record(:r9, dir: dir, compression: :gzip, file_bytes: 1)
    assert message =~ "recorder.compression: expected one of :zstd, :lz4, :none, got :gzip"
    assert message =~ "recorder.file_bytes: expected an integer from 65536"

    assert_raise ArgumentError, ~r/missing required key :robot/, fn ->
      Recorder.start_link(dir: dir)
    end

    assert BlackBox.recorder(:r9) == nil
    assert BlackBox.stop(:r9) == {:error, :not_recording}

    {:ok, _} = BlackBox.record(:r9, dir: dir)
    assert BlackBox.record(:r9, dir: dir) == {:error, :already_recording}
    :ok = BlackBox.stop(:r9)
  end

  test "a directory it cannot write to is an error at start, not a crash later", %{tmp_dir: dir} do
    file = Path.join(dir, "a_file")
    File.write!(file, "")
    assert {:error, {:cannot_record, _, _}} = BlackBox.record(:r8, dir: Path.join(file, "sub"))
  end
end
