defmodule ThinkingCap.Runtime.Application do
  @moduledoc false
  # The execution layer's supervision tree (rest_for_one: later children
  # depend on earlier ones):
  #
  #   :pg scope                  finds every node's modules
  #   ThinkingCap.Cycle          the timing worker's owner
  #   ThinkingCap.Runtime.Modules  DynamicSupervisor of module hosts
  #
  # One crash-looping module must not take the others down with the
  # supervisor, hence the generous restart intensity of Modules.
  use Application

  @impl true
  def start(_type, _args) do
    ThinkingCap.Runtime.Scheduling.apply_config()

    children = [
      %{id: :pg, start: {:pg, :start_link, [ThinkingCap.Runtime.scope()]}},
      ThinkingCap.Cycle,
      {DynamicSupervisor,
       name: ThinkingCap.Runtime.Modules,
       strategy: :one_for_one,
       max_restarts: 100,
       max_seconds: 10}
    ]

    Supervisor.start_link(children, strategy: :rest_for_one, name: ThinkingCap.Runtime.Supervisor)
  end
end
