defmodule ThinkingCap.Dashboard.Launcher do
  @moduledoc false
  # Starts the dashboard when ThinkingCap.Runtime starts, on this node, an
  # ADF whose `dashboard:` section enables it (the runtime announces every
  # ADF it starts as `{:adf, robot, %{node:, wdf:, dashboard:, ...}}`).
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Config.DashboardOptions
  alias ThinkingCap.Tuples
  require Tuples

  def start_link(_), do: GenServer.start_link(__MODULE__, nil, name: __MODULE__)

  @impl true
  def init(nil) do
    {:ok, _ref} = Blackboard.subscribe(Tuples.adf())
    {:ok, nil}
  end

  @impl true
  def handle_info({:blackboard, _ref, Tuples.adf(robot, %{node: node} = adf)}, state)
      when node == node() do
    dashboard = Map.new(adf[:dashboard] || %{})

    if dashboard[:enabled] && ThinkingCap.Dashboard.config() == nil do
      # the section was validated with the dashboard's own option fields
      opts =
        dashboard
        |> Map.take(DashboardOptions.keys())
        |> Map.put(:world, adf[:wdf])
        |> Enum.to_list()

      case ThinkingCap.Dashboard.start(opts) do
        {:ok, info} ->
          # never the token: logs outlive the run and others may read them
          Logger.info(
            "dashboard for #{inspect(robot)} on #{info.host}:#{info.port}" <>
              if(info.estop_port, do: ", E-stop port #{info.estop_port}", else: "")
          )

        {:error, reason} ->
          Logger.error("dashboard for #{inspect(robot)} could not start: #{inspect(reason)}")
      end
    end

    {:noreply, state}
  end

  def handle_info(_message, state), do: {:noreply, state}
end
