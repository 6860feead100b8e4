defmodule ThinkingCap.Control.Fuzzy.Set do
  @moduledoc """
  A fuzzy set over an output universe, sampled: `degrees` is a tuple of
  `n` membership degrees at the points `min + i (max - min) / (n - 1)`,
  `i = 0..n-1` (both ends included). Built by
  `ThinkingCap.Control.Fuzzy.evaluate/4`; combined with
  `ThinkingCap.Control.Fuzzy.clip/2` and `union/1`; turned into a crisp
  value by `ThinkingCap.Control.Fuzzy.defuzzify/2`.
  """

  defstruct universe: {0.0, 1.0}, degrees: {}

  @type t :: %__MODULE__{universe: {float(), float()}, degrees: tuple()}
end
