defmodule ThinkingCap.Dashboard.Core.ScrubTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Core.Scrub

  # tuples of two tags at random times (several at one time included)
  defp snapshot(seed) do
    :rand.seed(:exsss, {seed, 7, 11})

    entries =
      for _ <- 1..200 do
        tag = Enum.random([:pose, :laser])
        {Enum.random(1_000..1_300), {tag, :r1, System.unique_integer()}}
      end
      |> Enum.sort_by(&elem(&1, 0))

    %{robot: :r1, from: 1_000, to: 1_300, entries: entries, dropped: 0}
  end

  # each tag's last tuple at or before t, found by walking the list
  defp linear(entries, t) do
    for {time, {tag, _, payload}} <- entries, time <= t, reduce: %{} do
      acc -> Map.put(acc, tag, payload)
    end
  end

  test "at/2 finds each tag's last payload at or before an instant, as a walk would" do
    for seed <- 1..20 do
      snap = snapshot(seed)
      scrub = Scrub.new(snap, %{})

      for t <- 990..1_310 do
        want = linear(snap.entries, t)
        got = Scrub.at(scrub, t)

        for tag <- [:pose, :laser] do
          assert (got[tag] && elem(got[tag], 1)) == want[tag], "seed #{seed}, t #{t}, #{tag}"
        end
      end
    end
  end

  test "the index is the payload's place among its tag's tuples" do
    entries = [{10, {:map, :r1, :a}}, {20, {:pose, :r1, :p}}, {30, {:map, :r1, :b}}]
    scrub = Scrub.new(%{robot: :r1, from: 10, to: 40, entries: entries, dropped: 3}, %{})
    assert Scrub.at(scrub, 9) == %{map: nil, pose: nil}
    assert Scrub.at(scrub, 25) == %{map: {0, :a}, pose: {0, :p}}
    assert Scrub.at(scrub, 40) == %{map: {1, :b}, pose: {0, :p}}
    assert Scrub.counts(scrub) == %{map: 2, pose: 1}
  end

  test "a seed stands for a tag with no tuple in the span, and only for one" do
    entries = [{10, {:pose, :r1, :p}}]
    seeds = %{pose: :older, plan: :held}
    scrub = Scrub.new(%{robot: :r1, from: 10, to: 20, entries: entries, dropped: 0}, seeds)
    assert Scrub.at(scrub, 15) == %{pose: {0, :p}, plan: {:seed, :held}}
    assert Scrub.counts(scrub) == %{pose: 1, plan: 1}
  end
end
