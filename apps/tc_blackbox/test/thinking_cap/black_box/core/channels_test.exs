defmodule ThinkingCap.BlackBox.Core.ChannelsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Core.Channels
  alias ThinkingCap.MCAP.{Reader, Writer}

  # a robot's tuples: large ones thinned (the LPS, several a second of
  # its stamps), others not, one without a stamp, one not {tag, id, payload},
  # ones of Foxglove's own schemas, one whose JSON C leaves to Erlang
  defp tuples do
    lps = for k <- 0..24, do: {:lps, :r1, %{stamp: k * 0.1, bins: Enum.to_list(1..k)}}
    odom = for k <- 0..24, do: {:odom, :r1, %{stamp: k * 0.1, pose: {k * 1.0, 0.0, 0.0}}}

    Enum.zip(lps, odom)
    |> Enum.flat_map(&Tuple.to_list/1)
    |> Kernel.++([{:plan, :r1, %{goal: {1.0, 2.0}}}, {:pair, 1}])
    |> Kernel.++([
      {:pose, :r1, %{stamp: 2.5, pose: {1.0, 2.0, 0.5}}},
      {:laser, :r1, %{stamp: 2.6, ranges: [1.0, 2.5], angle_min: -1.0, angle_max: 1.0}},
      {:sonar, :r1, %{stamp: 2.65, ranges: [1.0, 5.0], headings: [0.0, 1.5]}},
      {:note, :r1, %{stamp: 2.7, text: "héllo", from: self()}},
      {:pose, :r1, %{stamp: 2.75, pose: :lost}},
      {:sim_pose, :r1, %{stamp: 2.76, pose: {1, 2, 3}}},
      {:odom, :r1, %{stamp: 2.8, pose: {1.0, 0.0, 0.0}}}
    ])
  end

  # `tuples` written one by one with `write`, into an MCAP file's bytes
  defp file(write, tuples \\ tuples()) do
    {:ok, w} = Writer.new(compression: "")

    {w, _chans} =
      tuples
      |> Enum.with_index(1)
      |> Enum.reduce({w, Channels.new(:r1)}, fn {tuple, n}, {w, chans} ->
        {:ok, w, chans, _} = write.(w, chans, tuple, n * 1_000_000)
        {w, chans}
      end)

    {:ok, bytes} = Writer.close(w)
    bytes
  end

  test "a tuple held as its writer made it (held/1) is recorded as the tuple itself" do
    as_tuples = file(&Channels.write_tuple/4)

    as_held =
      file(fn w, chans, t, time -> Channels.write_held(w, chans, Channels.held(t), time) end)

    assert as_held == as_tuples

    # the large tuples' terms all kept, their JSON once a second of their stamps
    {:ok, read} = Reader.read_binary(as_held)
    topics = Enum.frequencies(for m <- read.messages, do: read.channels[m.channel_id].topic)
    assert topics["/etf/r1/lps"] == 25
    assert topics["/r1/lps"] == 3
    assert topics["/etf/r1/odom"] == 26
    assert topics["/r1/odom"] == 26
    assert topics["/r1/note"] == 1
  end

  test "tuples written in runs (write_held_all/3) are recorded as one at a time" do
    one_by_one =
      file(fn w, chans, t, time -> Channels.write_held(w, chans, Channels.held(t), time) end)

    entries =
      tuples()
      |> Enum.with_index(1)
      |> Enum.map(fn {t, n} -> {Channels.held(t), n * 1_000_000} end)

    {:ok, w} = Writer.new(compression: "")

    {w, _chans, count} =
      entries
      |> Enum.chunk_every(7)
      |> Enum.reduce({w, Channels.new(:r1), 0}, fn run, {w, chans, count} ->
        {:ok, w, chans, n} = Channels.write_held_all(w, chans, run)
        {w, chans, count + n}
      end)

    {:ok, in_runs} = Writer.close(w)
    {:ok, a} = Reader.read_binary(one_by_one)
    {:ok, b} = Reader.read_binary(in_runs)
    assert count == length(b.messages)

    # the same messages on the same channels (a run's channels are
    # declared before its messages, so the records' order may differ)
    messages = fn file ->
      for m <- file.messages do
        channel = file.channels[m.channel_id]
        {channel.topic, channel.schema_id, m.sequence, m.log_time, m.publish_time, m.data}
      end
    end

    assert messages.(b) == messages.(a)
    assert b.statistics.channel_message_counts == a.statistics.channel_message_counts
  end

  test "held/1 keeps a tuple's term and kind, not the tuple, but for a map" do
    lps = {:lps, :r1, %{stamp: 1.5, bins: [1.0, 2.0]}}
    assert {Channels, :big, :lps, :r1, 1_500_000_000, etf} = Channels.held(lps)
    assert :erlang.binary_to_term(etf) == lps
    odom = {:odom, :r1, %{stamp: 1.5}}
    assert {Channels, :generic, :odom, :r1, 1_500_000_000, etf} = Channels.held(odom)
    assert etf == :erlang.term_to_binary(odom)
    assert {Channels, :generic, :plan, :r1, nil, _} = Channels.held({:plan, :r1, %{goal: 1}})
    pose = {:pose, :r1, %{stamp: 1.5, pose: {1.0, 2.0, 0.5}}}
    assert {Channels, :pose, :pose, :r1, 1_500_000_000, _} = Channels.held(pose)
    scan = {:laser, :r1, %{ranges: [1.0], angle_min: 0.0, angle_max: 0.0}}
    assert {Channels, :scan, :laser, :r1, nil, _} = Channels.held(scan)
    # ranges without angles: not a scan's shape, a thinkingcap.Tuple
    sonar = {:sonar, :r1, %{ranges: [1.0], headings: [0.0]}}
    assert {Channels, :generic, :sonar, :r1, nil, _} = Channels.held(sonar)
    map = {:map, :r1, %{width: 1}}
    assert {Channels, ^map, etf} = Channels.held(map)
    assert etf == :erlang.term_to_binary(map)
  end

  test "a pose or scan its schema's writer refuses goes to a channel of the generic schema" do
    good_pose = {:pose, :r1, %{stamp: 1.0, pose: {1.0, 2.0, 0.5}}}
    lost = {:pose, :r1, %{stamp: 1.1, pose: :lost}}
    good_scan = {:laser, :r1, %{stamp: 1.2, ranges: [1.0], angle_min: 0.0, angle_max: 0.0}}
    bad_scan = {:laser, :r1, %{stamp: 1.3, ranges: [:far], angle_min: 0.0, angle_max: 0.0}}

    for write <- [&Channels.write_tuple/4, &write_held/4],
        order <- [[good_pose, lost, good_scan, bad_scan], [lost, good_pose, bad_scan, good_scan]] do
      {:ok, read} = Reader.read_binary(file(write, order))

      json =
        for m <- read.messages,
            channel = read.channels[m.channel_id],
            channel.schema_id != 0,
            do:
              {channel.topic, read.schemas[channel.schema_id].name,
               :jiffy.decode(m.data, [:return_maps])}

      # each message has the fields of its channel's schema
      for {_topic, schema, data} <- json do
        case schema do
          "thinkingcap.Tuple" -> assert %{"tag" => _, "payload" => _} = data
          "foxglove.PoseInFrame" -> assert %{"pose" => %{"position" => _}} = data
          "foxglove.FrameTransform" -> assert %{"translation" => _} = data
          "foxglove.LaserScan" -> assert %{"ranges" => [_]} = data
        end
      end

      assert Enum.sort(for {topic, schema, _} <- json, do: {topic, schema}) == [
               {"/r1/laser", "foxglove.LaserScan"},
               {"/r1/laser", "thinkingcap.Tuple"},
               {"/r1/pose", "foxglove.PoseInFrame"},
               {"/r1/pose", "thinkingcap.Tuple"},
               {"/r1/tf", "foxglove.FrameTransform"}
             ]
    end
  end

  defp write_held(w, chans, tuple, time),
    do: Channels.write_held(w, chans, Channels.held(tuple), time)
end
