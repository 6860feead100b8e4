defmodule ThinkingCap.Runtime.Application do
  @moduledoc false
  # The execution layer's supervision tree: the periodic cycle (the timing
  # worker's owner). Hosted modules join it as the runtime lands.
  use Application

  @impl true
  def start(_type, _args) do
    children = [ThinkingCap.Cycle]
    Supervisor.start_link(children, strategy: :one_for_one, name: ThinkingCap.Runtime.Supervisor)
  end
end
