defmodule ThinkingCap.BlackboardCase do
  @moduledoc false
  # Every test gets its own robot id, so tests that share the node's
  # blackboard never see each other's tuples.
  use ExUnit.CaseTemplate

  using do
    quote do
      alias ThinkingCap.Blackboard
      import ThinkingCap.Blackboard.Assertions
    end
  end

  setup do
    %{id: make_ref()}
  end
end
