defmodule ThinkingCap.BlackBox.FoxgloveTest do
  use ExUnit.Case, async: true

  import Bitwise

  alias ThinkingCap.BlackBox.Core.Channels
  alias ThinkingCap.BlackBox.Core.JSON.Native
  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.MCAP.{Reader, Writer}
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  defp decode(json), do: :jiffy.decode(json, [:return_maps, :use_nil])

  defp one(tuple, time \\ 7_000_000_000) do
    [{topic, schema, json}] = Foxglove.messages(tuple, time)
    {topic, schema, decode(json)}
  end

  test "a laser reading is a foxglove.LaserScan in the robot's frame" do
    scan = %{
      ranges: [1.0, 2.5, 8.0],
      angle_min: -1.5,
      angle_max: 1.5,
      angle_increment: 1.5,
      range_min: 0.1,
      range_max: 8.0,
      stamp: 12.25
    }

    assert {"/r1/laser", "foxglove.LaserScan", json} = one(Tuples.reading(:laser, :r1, scan))
    assert json["timestamp"] == %{"sec" => 12, "nsec" => 250_000_000}
    assert json["frame_id"] == "r1/base_link"
    assert json["start_angle"] == -1.5 and json["end_angle"] == 1.5
    assert json["ranges"] == [1.0, 2.5, 8.0]
    assert json["intensities"] == []
    assert json["pose"]["orientation"] == %{"x" => 0, "y" => 0, "z" => 0, "w" => 1}
    assert Foxglove.stamp_ns(Tuples.reading(:laser, :r1, scan)) == 12_250_000_000
  end

  test "a scan's ranges are written to the millimetre" do
    scan = %{ranges: [1.23456789, 0.0004, 7, 2.9995001], angle_min: -1.0, angle_max: 1.0}
    assert {_, "foxglove.LaserScan", json} = one(Tuples.reading(:laser, :r1, scan))
    assert json["ranges"] == [1.235, 0.0, 7.0, 3.0]
  end

  test "the map is a foxglove.Grid of signed bytes, base64" do
    grid = %{
      OccupancyGrid.new(3, 2, resolution: 0.5, origin: {-1.0, 2.0})
      | data: <<0, 100, -1::signed-8, 50, 0, 0>>
    }

    assert {"/r1/map", "foxglove.Grid", json} = one(Tuples.map(:r1, grid))
    assert json["frame_id"] == "map"
    assert json["column_count"] == 3
    assert json["row_stride"] == 3 and json["cell_stride"] == 1
    assert json["cell_size"] == %{"x" => 0.5, "y" => 0.5}
    assert json["pose"]["position"] == %{"x" => -1.0, "y" => 2.0, "z" => 0.0}
    # foxglove.NumericType INT8 is 2
    assert json["fields"] == [%{"name" => "occupancy", "offset" => 0, "type" => 2}]
    assert Base.decode64!(json["data"]) == grid.data
    # no stamp: the time given
    assert json["timestamp"] == %{"sec" => 7, "nsec" => 0}
  end

  test "the pose estimate is a PoseInFrame in the map and the transform to the robot" do
    pose = Tuples.pose(:r1, %{pose: {1.0, 2.0, :math.pi() / 2}, covariance: nil, stamp: 3.0})

    assert [
             {"/r1/pose", "foxglove.PoseInFrame", p},
             {"/r1/tf", "foxglove.FrameTransform", t}
           ] = Foxglove.messages(pose, 0)

    p = decode(p)
    t = decode(t)
    assert p["frame_id"] == "map"
    assert p["pose"]["position"] == %{"x" => 1.0, "y" => 2.0, "z" => 0.0}
    # to the millionth
    assert_in_delta p["pose"]["orientation"]["z"], :math.sqrt(0.5), 1.0e-6
    assert_in_delta p["pose"]["orientation"]["w"], :math.sqrt(0.5), 1.0e-6
    assert t["parent_frame_id"] == "map" and t["child_frame_id"] == "r1/base_link"
    assert t["translation"] == p["pose"]["position"]
    assert t["rotation"] == p["pose"]["orientation"]
    assert t["timestamp"] == %{"sec" => 3, "nsec" => 0}
  end

  test "the simulator's truth is a PoseInFrame of its own" do
    assert {"/r1/sim_pose", "foxglove.PoseInFrame", json} =
             one(Tuples.sim_pose(:r1, %{pose: {4.0, 5.0, 0.0}, stamp: 1.5}))

    assert json["pose"]["orientation"]["w"] == 1.0
  end

  test "any other tuple is a thinkingcap.Tuple, whatever its payload holds" do
    payload = %{
      command: {:velocity, 0.5, -0.1},
      by: nil,
      flag: true,
      text: "héllo",
      bytes: <<255, 0, 1>>,
      bits: <<1::3>>,
      pid: self(),
      ref: make_ref(),
      fun: &Enum.map/2,
      improper: [1 | 2],
      nested: %{{:a, 1} => [:b], "k" => %URI{host: "x"}},
      big: 123_456_789_012_345_678_901_234_567_890
    }

    assert {"/r1/teleop", "thinkingcap.Tuple", json} = one(Tuples.teleop(:r1, payload))
    assert json["tag"] == "teleop" and json["robot"] == "r1"
    p = json["payload"]
    assert p["command"] == ["velocity", 0.5, -0.1]
    assert p["by"] == nil and p["flag"] == true
    assert p["text"] == "héllo"
    assert p["bytes"] == %{"base64" => Base.encode64(<<255, 0, 1>>)}
    assert p["pid"] == inspect(self())
    assert p["improper"] == [1, 2]
    assert p["nested"]["{:a, 1}"] == ["b"]
    assert p["nested"]["k"]["__struct__"] == "URI" and p["nested"]["k"]["host"] == "x"
    assert p["big"] == 123_456_789_012_345_678_901_234_567_890
  end

  test "a known tag with an unexpected payload is recorded as it is, not lost" do
    assert {"/r1/laser", "thinkingcap.Tuple", json} =
             one(Tuples.reading(:laser, :r1, %{ranges: [1.0, :nan], angle_min: 0, angle_max: 1}))

    assert json["payload"]["ranges"] == [1.0, "nan"]
    assert {"/r1/map", "thinkingcap.Tuple", _} = one(Tuples.map(:r1, %{bogus: true}))
    # ids that are not robots (an activity's timing) name the topic too
    assert {"/base/timing", "thinkingcap.Tuple", _} = one(Tuples.timing(:base, %{cycles: 1}))
  end

  # numbers of every kind a payload may hold, and now and then something
  # else, or a key missing
  defp some_number do
    Enum.random([
      (:rand.uniform() - 0.5) * 20,
      Float.round(:rand.uniform() * 10, 3) + 0.0005,
      :rand.uniform(1000) * 1.0e14,
      1.0e-5,
      -0.0,
      :rand.uniform(100) - 50,
      1 <<< 62
    ])
  end

  defp maybe(x), do: if(:rand.uniform(15) == 1, do: Enum.random([:a, "x", nil, [1 | 2]]), else: x)

  defp random_kinded do
    robot = maybe(Enum.random([:r1, :rb_17, :"r ö"]))
    stamp = Enum.random([[stamp: :rand.uniform() * 100], [stamp: 3], [stamp: -1.0], []])

    case :rand.uniform(4) do
      1 ->
        ranges =
          Enum.random([
            Enum.map(1..:rand.uniform(20), fn _ -> maybe(some_number()) end),
            [],
            [1, 2, 3]
          ])

        payload = %{ranges: maybe(ranges), angle_min: maybe(some_number()), angle_max: -1.5}
        {Enum.random([:laser, :sonar, :pose]), robot, Map.merge(payload, Map.new(stamp))}

      2 ->
        pose = maybe({some_number(), some_number(), maybe(some_number())})
        {:pose, robot, Map.merge(%{pose: pose, sigma: [0.1]}, Map.new(stamp))}

      3 ->
        {:sim_pose, robot,
         Map.merge(%{pose: {some_number(), 1.5, some_number()}}, Map.new(stamp))}

      4 ->
        {Enum.random([:odom, :drive]), robot, Map.merge(%{v: some_number()}, Map.new(stamp))}
    end
  end

  test "a tuple's messages read from its external term in C are the same" do
    time = 7_000_000_000

    written =
      for _ <- 1..3_000, reduce: 0 do
        n ->
          {tag, id, _} = tuple = random_kinded()
          kind = Foxglove.kind(tuple)
          publish = Foxglove.stamp_ns(tuple) || time
          expected = Foxglove.messages(tuple, time)

          case Native.messages_etf(kind, :erlang.term_to_binary(tuple), publish) do
            false ->
              n

            jsons ->
              assert jsons == Enum.map(expected, &IO.iodata_to_binary(elem(&1, 2)))
              assert Foxglove.topics(kind, tag, id) == Enum.map(expected, &Tuple.delete_at(&1, 2))
              n + 1
          end
      end

    # most of them (the rest left to Erlang: bad shapes, a robot not ASCII)
    assert written > 1_500
  end

  test "tuples held as their terms are written straight into the chunk as Erlang writes them" do
    tuples =
      for _ <- 1..600 do
        if :rand.uniform(4) == 1,
          do: {:sonar, :r1, %{ranges: [5.0, 0.25, 1], headings: [0.0, 1.5], stamp: 2.5}},
          else: random_kinded()
      end

    times = Enum.map(1..length(tuples), &(&1 * 1_000_000))
    # small chunks, so that some close between a tuple's messages
    new = fn -> elem(Writer.new(compression: "", chunk_bytes: 3_000), 1) end

    {w, _} =
      Enum.zip(tuples, times)
      |> Enum.reduce({new.(), Channels.new(:r1)}, fn {t, time}, {w, chans} ->
        {:ok, w, chans, _} = Channels.write_tuple(w, chans, t, time)
        {w, chans}
      end)

    {:ok, in_erlang} = Writer.close(w)

    {w, _, count} =
      Enum.zip(Enum.map(tuples, &Channels.held/1), times)
      |> Enum.chunk_every(32)
      |> Enum.reduce({new.(), Channels.new(:r1), 0}, fn run, {w, chans, count} ->
        {:ok, w, chans, n} = Channels.write_held_all(w, chans, run)
        {w, chans, count + n}
      end)

    {:ok, in_c} = Writer.close(w)
    {:ok, a} = Reader.read_binary(in_erlang)
    {:ok, b} = Reader.read_binary(in_c)
    assert count == length(b.messages)
    assert b.chunks > 10

    messages = fn file ->
      for m <- file.messages do
        channel = file.channels[m.channel_id]
        schema = if channel.schema_id > 0, do: file.schemas[channel.schema_id].name
        {channel.topic, schema, m.sequence, m.log_time, m.publish_time, m.data}
      end
    end

    assert messages.(b) == messages.(a)
  end

  test "every schema is a JSON schema titled with its name" do
    for name <- Foxglove.schema_names() do
      schema = decode(Foxglove.schema(name))
      assert schema["title"] == name and schema["type"] == "object"
    end

    assert Enum.sort(Foxglove.schema_names()) == [
             "foxglove.FrameTransform",
             "foxglove.Grid",
             "foxglove.LaserScan",
             "foxglove.PoseInFrame",
             "thinkingcap.Tuple"
           ]
  end
end
