defmodule ThinkingCap.Sim.Core.Contacts do
  @moduledoc false
  # Robot-robot contacts within a step. The robots of a step move at once,
  # each checking the others where they stood, so two robots may both move
  # into the gap between them and overlap. Given every robot's move, this
  # finds the pairs that end overlapping and nearer than they were; both
  # moves of such a pair are taken back. That is enough: every other robot
  # checked its move against where these two stood, and they stay there.
  # A uniform grid of buckets by new position (as wide as the largest
  # contact distance) keeps it linear in the number of robots.

  @typedoc "A robot's move: its body index, where it stood, where it moved to and its radius."
  @type move :: {non_neg_integer(), {float(), float()}, {float(), float(), float()}, float()}

  @doc "The body indexes of the moves to take back."
  @spec taken_back([move()]) :: MapSet.t(non_neg_integer())
  def taken_back([]), do: MapSet.new()

  def taken_back(moves) do
    h = 2 * Enum.reduce(moves, 0.0, fn {_, _, _, r}, acc -> max(r, acc) end)
    h = if h > 0, do: h, else: 1.0

    grid =
      Enum.reduce(moves, %{}, fn {_, _, {x, y, _}, _} = m, grid ->
        Map.update(grid, cell(x, y, h), [m], &[m | &1])
      end)

    Enum.reduce(moves, MapSet.new(), fn {i, _, {x, y, _}, _} = m, acc ->
      {cx, cy} = cell(x, y, h)

      for dx <- -1..1,
          dy <- -1..1,
          {j, _, _, _} = o <- Map.get(grid, {cx + dx, cy + dy}, []),
          j > i,
          clash?(m, o),
          reduce: acc do
        acc -> acc |> MapSet.put(i) |> MapSet.put(j)
      end
    end)
  end

  defp cell(x, y, h), do: {floor(x / h), floor(y / h)}

  defp clash?({_, {ax, ay}, {ax2, ay2, _}, ar}, {_, {bx, by}, {bx2, by2, _}, br}) do
    now = (ax2 - bx2) ** 2 + (ay2 - by2) ** 2
    now < (ar + br) ** 2 and now < (ax - bx) ** 2 + (ay - by) ** 2
  end
end
