defmodule ThinkingCap.Sim.Core.RegionsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim.Core.Regions

  # the shard of every robot once the handovers are made
  defp apply_plan(plan, current) do
    Enum.reduce(plan, current, fn {from, to, ids}, acc ->
      Enum.reduce(ids, acc, fn id, acc ->
        assert acc[id] == from
        Map.put(acc, id, to)
      end)
    end)
  end

  test "robots near each other end in the same shard, the shards equally loaded" do
    [a, b, c] = shards = for k <- 1..3, do: :c.pid(0, 900 + k, 0)
    # three clusters far apart (one across the origin), dealt round-robin
    clusters = [{-60.0, -40.0}, {-0.2, 0.3}, {80.0, 10.0}]

    robots =
      for k <- 0..29 do
        {cx, cy} = Enum.at(clusters, rem(k, 3))
        {:"r#{k}", k, cx + rem(k, 5) * 0.7, cy + div(k, 10) * 0.9}
      end

    current = Map.new(robots, fn {id, k, _, _} -> {id, Enum.at(shards, rem(k, 2))} end)
    plan = Regions.plan(robots, shards, current)
    after_plan = apply_plan(plan, current)

    by_shard = Enum.group_by(robots, fn {id, _, _, _} -> after_plan[id] end)
    assert Enum.map([a, b, c], &length(by_shard[&1])) == [10, 10, 10]

    for {_shard, members} <- by_shard do
      cluster = fn {_, k, _, _} -> rem(k, 3) end
      assert members |> Enum.map(cluster) |> Enum.uniq() |> length() == 1
    end

    # nothing more to do, and robots that moved a little stay
    assert Regions.plan(robots, shards, after_plan) == []

    nudged = for {id, k, x, y} <- robots, do: {id, k, x + 0.01, y}
    assert Regions.plan(nudged, shards, after_plan) == []
    assert Regions.plan([], shards, %{}) == []
  end
end
