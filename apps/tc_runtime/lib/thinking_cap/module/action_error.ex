defmodule ThinkingCap.Module.ActionError do
  @moduledoc """
  Raised where a module's callback returned what the framework cannot
  read: not `{actions, state}`, or an action outside the vocabulary of
  `ThinkingCap.Module` (a misspelt `{:outt, tuple}`, an `:out` of a
  number). The message names the module, the callback and the action, and
  lists the known actions:

      MyMod.handle_cycle/2 returned an unknown action {:outt, {:x, :r1, 1}}; known: ...

  The hosting process (`ThinkingCap.Runtime`) and the lockstep harness
  (`ThinkingCap.Testing.Lockstep`) raise it alike: a hosted module stops
  with it (and its supervisor starts it again), a lockstep test fails with
  it.
  """

  defexception [:module, :callback, :action, :message]

  @type t :: %__MODULE__{
          module: module(),
          callback: atom(),
          action: term(),
          message: String.t()
        }
end
