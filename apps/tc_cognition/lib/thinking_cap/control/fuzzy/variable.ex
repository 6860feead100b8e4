defmodule ThinkingCap.Control.Fuzzy.Variable do
  @moduledoc """
  A linguistic variable: a `name`, a `universe` `{min, max}` and its
  `terms`, a map of term names to membership functions
  (`t:ThinkingCap.Control.Fuzzy.membership/0`). Build one with
  `ThinkingCap.Control.Fuzzy.variable/3`, which checks the terms.
  """

  defstruct name: nil, universe: {0.0, 1.0}, terms: %{}

  @type t :: %__MODULE__{
          name: atom(),
          universe: {float(), float()},
          terms: %{atom() => ThinkingCap.Control.Fuzzy.membership()}
        }
end
