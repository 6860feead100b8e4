defmodule ThinkingCap.Blackboard.Application do
  @moduledoc false
  # Supervision topology (rest_for_one: a later child depends on the earlier):
  #
  #   :pg scope           cluster membership of the blackboard servers
  #   Core.Tables         owns the ETS tables, runs no other code
  #   Core.EvalSupervisor Task.Supervisor for eval/1
  #   Core.Replicator     sends this node's writes to the other nodes
  #   Core.Server         applies other nodes' writes, replicates takes,
  #                       snapshots, waiter wake-ups, monitors, expiry
  #   Core.Batches        sends batched subscriptions their lists
  use Application

  alias ThinkingCap.Blackboard.Core

  @impl true
  def start(_type, _args) do
    children = [
      %{id: :pg, start: {:pg, :start_link, [Core.Server.scope()]}},
      Core.Tables,
      {Task.Supervisor, name: Core.EvalSupervisor},
      Core.Replicator,
      Core.Server,
      Core.Batches
    ]

    Supervisor.start_link(children,
      strategy: :rest_for_one,
      max_restarts: 20,
      max_seconds: 10,
      name: ThinkingCap.Blackboard.Supervisor
    )
  end
end
