defmodule ThinkingCap.Sim.Core.Contacts do
  @moduledoc false
  # Robot-robot contacts within a step. The robots of a step move at once,
  # each checking the others where they stood, so two robots may both move
  # into the gap between them and overlap. Given every robot's move, this
  # finds the pairs that end overlapping and nearer than they were; both
  # moves of such a pair are taken back. That is enough: every other robot
  # checked its move against where these two stood, and they stay there.
  # The search is the ray caster's (Raycast.contacts/1, a grid of buckets:
  # linear in the number of robots).

  alias ThinkingCap.Sim.Raycast

  @doc """
  The body indexes of the moves to take back. `moves` is iodata of
  `Raycast.move_record/6` records (a binary per shard).
  """
  @spec taken_back(iodata()) :: MapSet.t(non_neg_integer())
  def taken_back(moves), do: moves |> IO.iodata_to_binary() |> Raycast.contacts() |> MapSet.new()
end
