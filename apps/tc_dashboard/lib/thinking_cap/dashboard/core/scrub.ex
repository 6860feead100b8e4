defmodule ThinkingCap.Dashboard.Core.Scrub do
  @moduledoc false
  # A black box's snapshot indexed for scrubbing, a pure value: per tag,
  # the receipt times and the payloads in order (tuples, so that `at/2`
  # finds each tag's latest payload at an instant by binary search).
  #
  # A tag with no tuple in the snapshot may have a seed: its value on the
  # blackboard, read just before the snapshot was taken. No tuple of it
  # came during the snapshot's span, so that value held all along. A tag
  # that has tuples has nothing before its first one (what came before
  # the span is gone).

  defstruct [:robot, :from, :to, streams: %{}, seeds: %{}, dropped: 0]

  @type t :: %__MODULE__{
          robot: atom(),
          from: integer(),
          to: integer(),
          streams: %{atom() => {tuple(), tuple()}},
          seeds: %{atom() => term()},
          dropped: non_neg_integer()
        }

  # which of a tag's payloads is shown: its index in the snapshot, or
  # :seed for the value from the blackboard
  @type pick :: {non_neg_integer() | :seed, term()} | nil

  # `snapshot` as BlackBox.snapshot/2 answers it; `seeds` tag => payload
  @spec new(map(), %{atom() => term()}) :: t()
  def new(snapshot, seeds) do
    streams =
      snapshot.entries
      |> Enum.group_by(fn {_t, tuple} -> elem(tuple, 0) end, fn {t, tuple} ->
        {t, elem(tuple, 2)}
      end)
      |> Map.new(fn {tag, list} ->
        {times, payloads} = Enum.unzip(list)
        {tag, {List.to_tuple(times), List.to_tuple(payloads)}}
      end)

    %__MODULE__{
      robot: snapshot.robot,
      from: snapshot.from,
      to: snapshot.to,
      streams: streams,
      seeds: Map.drop(seeds, Map.keys(streams)),
      dropped: snapshot.dropped
    }
  end

  # How many tuples of each tag it holds (a seed counts one).
  @spec counts(t()) :: %{atom() => non_neg_integer()}
  def counts(scrub) do
    Map.merge(
      Map.new(scrub.seeds, fn {tag, _} -> {tag, 1} end),
      Map.new(scrub.streams, fn {tag, {times, _}} -> {tag, tuple_size(times)} end)
    )
  end

  # What each tag showed at `t` (ns since the epoch): its latest payload
  # received at or before `t`, or nil.
  @spec at(t(), integer()) :: %{atom() => pick()}
  def at(scrub, t) do
    seeds = Map.new(scrub.seeds, fn {tag, payload} -> {tag, {:seed, payload}} end)

    Enum.into(scrub.streams, seeds, fn {tag, {times, payloads}} ->
      case last_at_or_before(times, t) do
        nil -> {tag, nil}
        i -> {tag, {i, elem(payloads, i)}}
      end
    end)
  end

  # the index of the last time <= t in a sorted tuple, or nil
  defp last_at_or_before(times, t) do
    if tuple_size(times) == 0 or elem(times, 0) > t,
      do: nil,
      else: search(times, t, 0, tuple_size(times) - 1)
  end

  # times[lo] <= t holds; the answer is in lo..hi
  defp search(_times, _t, lo, lo), do: lo

  defp search(times, t, lo, hi) do
    mid = div(lo + hi + 1, 2)
    if elem(times, mid) <= t, do: search(times, t, mid, hi), else: search(times, t, lo, mid - 1)
  end
end
