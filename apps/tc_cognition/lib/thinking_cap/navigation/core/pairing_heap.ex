defmodule ThinkingCap.Navigation.Core.PairingHeap do
  @moduledoc false
  # A min pairing heap of entries ordered by a two-part key `{a, b}`
  # (lexicographic; `a` and `b` are numbers), each carrying a value. Used
  # by the planners with lazy deletion: a stale entry stays in the heap and
  # is skipped by its user when popped. `nil` is the empty heap; a node is
  # `{a, b, value, children}`.

  @type t :: nil | {number(), number(), term(), [t()]}

  @doc false
  @spec insert(t(), number(), number(), term()) :: t()
  def insert(nil, a, b, value), do: {a, b, value, []}

  def insert({ha, hb, hv, hc} = heap, a, b, value) do
    if a < ha or (a == ha and b < hb),
      do: {a, b, value, [heap]},
      else: {ha, hb, hv, [{a, b, value, []} | hc]}
  end

  @doc false
  @spec pop(t()) :: {number(), number(), term(), t()} | :empty
  def pop(nil), do: :empty
  def pop({a, b, value, children}), do: {a, b, value, merge_pairs(children)}

  @doc false
  @spec min(t()) :: {number(), number(), term()} | :empty
  def min(nil), do: :empty
  def min({a, b, value, _}), do: {a, b, value}

  @doc false
  @spec meld(t(), t()) :: t()
  def meld(nil, h), do: h
  def meld(h, nil), do: h

  def meld({a1, b1, v1, c1} = h1, {a2, b2, v2, c2} = h2) do
    if a1 < a2 or (a1 == a2 and b1 <= b2),
      do: {a1, b1, v1, [h2 | c1]},
      else: {a2, b2, v2, [h1 | c2]}
  end

  defp merge_pairs([]), do: nil
  defp merge_pairs([h]), do: h
  defp merge_pairs([h1, h2 | rest]), do: meld(meld(h1, h2), merge_pairs(rest))
end
