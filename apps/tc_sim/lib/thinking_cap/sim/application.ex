defmodule ThinkingCap.Sim.Application do
  @moduledoc false
  use Application

  @impl true
  def start(_type, _args) do
    children = [
      {Registry, keys: :unique, name: ThinkingCap.Sim.Registry},
      {DynamicSupervisor, name: ThinkingCap.Sim.Supervisor, strategy: :one_for_one}
    ]

    Supervisor.start_link(children, strategy: :one_for_one, name: ThinkingCap.Sim.AppSupervisor)
  end
end
