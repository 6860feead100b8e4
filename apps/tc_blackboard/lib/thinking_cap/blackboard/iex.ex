defmodule ThinkingCap.Blackboard.IEx do
  @moduledoc """
  Helpers to inspect the blackboard from a (remote) IEx shell:

      iex> import ThinkingCap.Blackboard.IEx
      iex> bb_ls({:pose, :_, :_})
      iex> bb_count()
      iex> bb_subscriptions()

  Every node holds replicas of every connected node's tuples, so `bb_ls/2`
  and `bb_count/0` on any node show the whole space. Subscriptions and
  blocked waiters are per node: `bb_subscriptions/1` takes a node.
  """

  alias ThinkingCap.Blackboard

  @doc """
  Prints the tuples matching `template` (all of them by default), at most
  `limit`, and returns how many matched.
  """
  @spec bb_ls(Blackboard.template() | :all, pos_integer()) :: non_neg_integer()
  def bb_ls(template \\ :all, limit \\ 50) do
    tuples = if template == :all, do: all_tuples(), else: Blackboard.rd_all(template)
    tuples |> Enum.take(limit) |> Enum.each(&IO.puts(inspect(&1, pretty: true, limit: 12)))
    if length(tuples) > limit, do: IO.puts("... #{length(tuples) - limit} more")
    length(tuples)
  end

  @doc "Counts the tuples on the blackboard by `{tag, arity}`."
  @spec bb_count() :: %{{term(), non_neg_integer()} => pos_integer()}
  def bb_count do
    Enum.frequencies_by(all_tuples(), fn
      {} -> {nil, 0}
      tuple -> {elem(tuple, 0), tuple_size(tuple)}
    end)
  end

  @doc "The subscriptions on `node` (this node by default)."
  @spec bb_subscriptions(node()) :: [map()]
  def bb_subscriptions(node \\ node()), do: :erpc.call(node, Blackboard, :subscriptions, [])

  @doc "The blocked `rd`/`take` requests on `node` (this node by default)."
  @spec bb_waiters(node()) :: [map()]
  def bb_waiters(node \\ node()), do: :erpc.call(node, Blackboard, :waiters, [])

  @doc "The nodes whose blackboard this node replicates to and from."
  @spec bb_peers() :: [node()]
  def bb_peers, do: ThinkingCap.Blackboard.Core.Server.peers() |> Enum.map(&node/1) |> Enum.sort()

  defp all_tuples do
    ThinkingCap.Blackboard.Core.Store.all_tuples()
  end
end
