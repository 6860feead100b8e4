defmodule ThinkingCap.Sim.Core.Regions do
  @moduledoc false
  # Which shard steps which robot: robots near each other go to the same
  # shard, so that a shard casts its robots' rays one after the other over
  # the same part of the map, which stays in the CPU's caches (1,000 robots
  # scattered over a 150 m x 100 m map cast ~1.6x slower in random order
  # than in spatial order). Robots are ranked along a Z-order curve of
  # 0.5 m cells and cut into runs of equal length, one per shard in order.
  # Where the shards stand does not change any result, only the speed.

  import Bitwise

  @cell 0.5

  @typedoc "A robot: its id, its body index and where it stands."
  @type robot :: {term(), non_neg_integer(), float(), float()}

  @doc """
  The handovers that bring every robot to the shard of its run:
  `[{from, to, [id]}]`, ids in rank order. `current` maps a robot id to
  its shard; `shards` lists the shards in order.
  """
  @spec plan([robot()], [pid()], %{term() => pid()}) :: [{pid(), pid(), [term()]}]
  def plan([], _shards, _current), do: []

  def plan(robots, shards, current) do
    n = length(robots)
    s = length(shards)
    shards = List.to_tuple(shards)

    robots
    |> Enum.map(fn {id, index, x, y} -> {{key(x, y), index}, id} end)
    |> Enum.sort()
    |> Enum.with_index()
    |> Enum.reduce(%{}, fn {{_key, id}, rank}, acc ->
      from = Map.fetch!(current, id)
      to = elem(shards, div(rank * s, n))
      if from == to, do: acc, else: Map.update(acc, {from, to}, [id], &[id | &1])
    end)
    |> Enum.map(fn {{from, to}, ids} -> {from, to, Enum.reverse(ids)} end)
    |> Enum.sort_by(fn {from, to, _} -> {index_of(shards, from), index_of(shards, to)} end)
  end

  defp index_of(shards, pid),
    do: Enum.find_index(Tuple.to_list(shards), &(&1 == pid))

  # the Z-order (Morton) key of the 0.5 m cell of (x, y), 24 bits a side
  # (about 4 km each way from the origin); farther away a cell wraps,
  # which costs speed, never a result
  defp key(x, y), do: interleave(coord(x)) ||| interleave(coord(y)) <<< 1

  defp coord(v), do: floor(v / @cell) + 0x800000 &&& 0xFFFFFF

  defp interleave(v) do
    Enum.reduce(0..23, 0, fn bit, acc -> acc ||| (v >>> bit &&& 1) <<< (2 * bit) end)
  end
end
