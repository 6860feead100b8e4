defmodule ThinkingCap.BlackBox.Application do
  @moduledoc false
  use Application

  @impl true
  def start(_type, _args) do
    children = []
    Supervisor.start_link(children, strategy: :one_for_one, name: ThinkingCap.BlackBox.Supervisor)
  end
end
