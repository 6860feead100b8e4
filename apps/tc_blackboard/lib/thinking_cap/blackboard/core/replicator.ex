defmodule ThinkingCap.Blackboard.Core.Replicator do
  @moduledoc false
  # Sends this node's writes to the other nodes' servers, so that a writer
  # pays a local message instead of a distribution send (an encode and a
  # socket write) on its own path. One process: a writer's tuples leave in
  # the order written. The peer list is the one the writer saw when it
  # wrote, which keeps the server's publish-then-snapshot rule intact.
  #
  # If this process dies, the messages in its mailbox are lost to the other
  # nodes; it is supervised rest_for_one before the server, whose restart
  # sends every peer a fresh snapshot, which repairs them.
  use GenServer

  alias ThinkingCap.Blackboard.Core.{Store, Tables}

  def start_link(_opts), do: GenServer.start_link(__MODULE__, :ok, name: __MODULE__)

  @doc false
  @spec replicate([pid()], Store.record()) :: :ok
  def replicate(peers, record) do
    case Process.whereis(__MODULE__) do
      nil -> :ok
      pid -> send(pid, {:replicate, peers, record})
    end

    :ok
  end

  @impl true
  def init(:ok), do: {:ok, nil}

  @impl true
  def handle_info({:replicate, peers, {key, _, _, _, _} = record}, state) do
    # whether it is still there: a tuple taken before it left is delivered
    # to the other nodes' subscribers but not stored there
    message = {:replica_out, node(), Tables.boot_id(), Store.to_wire(record), Store.member?(key)}
    Enum.each(peers, &send(&1, message))
    {:noreply, state}
  end
end
