defmodule ThinkingCap.Dashboard.Foxglove.StreamsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Foxglove.{Channels, Session, Streams}

  # a session with r1's pose and transform channels, a client subscribed to both
  defp session do
    specs = Enum.filter(Channels.of_robot(:r1, %{}), &(&1.tag == :pose))
    channels = specs |> Enum.with_index(1) |> Map.new(fn {c, id} -> {id, Map.put(c, :id, id)} end)

    %{
      Session.new()
      | channels: channels,
        by_topic: Map.new(channels, fn {id, c} -> {c.topic, id} end),
        subs: %{10 => 1, 11 => 2}
    }
  end

  test "a pose goes to its pose and transform channels" do
    {frames, _} = Streams.publish(session(), {:pose, :r1, %{stamp: 1.0, pose: {1.0, 2.0, 0.0}}})
    assert length(frames) == 2
  end

  test "a pose its schema cannot hold (lost) is not sent as a PoseInFrame" do
    assert {[], _} = Streams.publish(session(), {:pose, :r1, %{stamp: 1.0, pose: :lost}})
  end
end
