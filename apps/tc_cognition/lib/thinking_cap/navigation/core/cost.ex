defmodule ThinkingCap.Navigation.Core.Cost do
  @moduledoc false
  # The planners' cost model in exact integer arithmetic: a straight step
  # costs 2^36 units, a diagonal one round(√2 · 2^36) (an odd number, so two
  # paths cost the same units exactly when they have the same numbers of
  # straight and diagonal steps). The rounding error, under 0.5 units a
  # step, stays far below the smallest difference between two distinct
  # path costs of up to ~10^5 diagonal steps, so the integer optimum is
  # the real optimum. Costs reported to users are floats in cells.

  import Bitwise

  @straight 1 <<< 36
  @diagonal round(:math.sqrt(2) * (1 <<< 36))

  @doc false
  defmacro straight, do: @straight

  @doc false
  defmacro diagonal, do: @diagonal

  @doc false
  @spec octile(integer(), integer(), integer(), integer()) :: non_neg_integer()
  def octile(c1, r1, c2, r2) do
    dx = abs(c1 - c2)
    dy = abs(r1 - r2)

    if dx > dy,
      do: @straight * (dx - dy) + @diagonal * dy,
      else: @straight * (dy - dx) + @diagonal * dx
  end

  @doc false
  # the cost in units of a path of adjacent cells on a grid's bytes: each
  # step's length times 1 + (p(a) + p(b)) / 16, p(v) = v from 2 up, as
  # c_src/tc_plan.c counts it; nil if a cell is blocked (1) or outside
  @spec units(binary(), pos_integer(), pos_integer(), [{integer(), integer()}]) ::
          non_neg_integer() | nil
  def units(cells, w, h, [first | rest]) do
    byte = fn {c, r} ->
      if c >= 0 and r >= 0 and c < w and r < h, do: :binary.at(cells, r * w + c), else: 1
    end

    Enum.reduce_while(rest, {0, first, byte.(first)}, fn {c, r} = cell, {sum, {pc, pr}, pb} ->
      b = byte.(cell)
      base = if c != pc and r != pr, do: @diagonal, else: @straight

      if b == 1 or pb == 1,
        do: {:halt, nil},
        else: {:cont, {sum + step(base, pb, b), cell, b}}
    end)
    |> case do
      nil -> nil
      {sum, _, _} -> sum
    end
  end

  defp step(base, a, b) do
    case penalty(a) + penalty(b) do
      0 -> base
      p -> base + (base >>> 4) * p
    end
  end

  defp penalty(v) when v >= 2, do: v
  defp penalty(_v), do: 0

  @doc false
  @spec path_cost([{integer(), integer()}]) :: float()
  def path_cost([first | rest]) do
    {straight, diagonal, _} =
      Enum.reduce(rest, {0, 0, first}, fn {c, r} = cell, {s, d, {pc, pr}} ->
        if c != pc and r != pr, do: {s, d + 1, cell}, else: {s + 1, d, cell}
      end)

    straight + diagonal * :math.sqrt(2)
  end
end
