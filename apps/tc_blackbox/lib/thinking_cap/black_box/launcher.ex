defmodule ThinkingCap.BlackBox.Launcher do
  @moduledoc false
  # Starts a robot's recorder when ThinkingCap.Runtime starts, on this
  # node, an ADF whose `record:` section enables it (the runtime announces
  # every ADF it starts as `{:adf, robot, %{node:, record:, ...}}`; it
  # checked the section when it read the file).
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
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
    record = Map.new(adf[:record] || %{})

    if record[:enabled] do
      opts = record |> Map.delete(:enabled) |> Enum.to_list()

      case ThinkingCap.BlackBox.record(robot, opts) do
        {:ok, _pid} ->
          Logger.info("recording #{inspect(robot)} into #{Path.expand(record[:dir] || ".")}")

        {:error, :already_recording} ->
          :ok

        {:error, reason} ->
          Logger.error("recorder for #{inspect(robot)} could not start: #{inspect(reason)}")
      end
    end

    {:noreply, state}
  end

  def handle_info(_message, state), do: {:noreply, state}
end
