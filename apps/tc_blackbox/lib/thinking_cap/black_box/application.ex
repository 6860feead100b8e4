defmodule ThinkingCap.BlackBox.Application do
  @moduledoc false
  use Application

  @impl true
  def start(_type, _args) do
    children = [
      {Registry, keys: :unique, name: ThinkingCap.BlackBox.Registry},
      # a recorder that fails again and again (a full disk retries without
      # crashing) must not take the others down
      {DynamicSupervisor,
       name: ThinkingCap.BlackBox.Recorders,
       strategy: :one_for_one,
       max_restarts: 10,
       max_seconds: 60},
      # the robots' ring buffers, and the tasks writing their dumps
      {DynamicSupervisor,
       name: ThinkingCap.BlackBox.RingBuffers,
       strategy: :one_for_one,
       max_restarts: 10,
       max_seconds: 60},
      {Task.Supervisor, name: ThinkingCap.BlackBox.DumpWriters},
      ThinkingCap.BlackBox.Launcher
    ]

    Supervisor.start_link(children, strategy: :one_for_one, name: ThinkingCap.BlackBox.Supervisor)
  end
end
