defmodule ThinkingCap.Test.Buckets do
  @moduledoc false
  # Tags whose tag-only subscriptions share a flag bucket.

  alias ThinkingCap.Blackboard.Core.Tables

  @doc """
  Two new tags (arity-3 tuples) whose bucket holds no tag-only subscription
  now. Drawn until two collide (some 40 draws over 1,024 buckets): an
  atom's hash need not reach every bucket for one name pattern, so a search
  for one given bucket could run on.
  """
  def two_tags_in_a_free_bucket(prefix) do
    base = System.unique_integer([:positive])

    {_a, _b} =
      Enum.reduce_while(1..100_000, %{}, fn i, seen ->
        tag = :"#{prefix}_#{base}_#{i}"
        bucket = Tables.tag_bucket(3, tag)

        cond do
          Tables.tag_indexed?(3, tag) -> {:cont, seen}
          Map.has_key?(seen, bucket) -> {:halt, {seen[bucket], tag}}
          true -> {:cont, Map.put(seen, bucket, tag)}
        end
      end)
  end
end
