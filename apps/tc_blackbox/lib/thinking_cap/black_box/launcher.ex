defmodule ThinkingCap.BlackBox.Launcher do
  @moduledoc false
  # Starts a robot's recorder and ring buffer when ThinkingCap.Runtime
  # starts, on this node, an ADF whose `record:` and `black_box:`
  # sections enable them (the runtime announces every ADF it starts as
  # `{:adf, robot, %{node:, record:, black_box:, ...}}`; it checked the
  # sections when it read the file). The black box's `enabled:` unset is
  # this app's `:black_box_by_default` env (default true).
  #
  # The recorder starts before the ADF's modules: the runtime tells this
  # process of the ADF and waits for it (ThinkingCap.Runtime.Starting), so
  # that the modules are traced from their init (a replay needs it). The
  # announcement, after, starts it for an ADF started otherwise.
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Runtime.Starting
  alias ThinkingCap.Tuples
  require Tuples

  def start_link(_), do: GenServer.start_link(__MODULE__, nil, name: __MODULE__)

  @impl true
  def init(nil) do
    {:ok, _ref} = Blackboard.subscribe(Tuples.adf())
    :ok = Starting.listen()
    {:ok, nil}
  end

  @impl true
  def handle_info({:tc_adf_starting, _ref, _from, robot, adf} = starting, state) do
    record(robot, adf)
    Starting.ready(starting)
    {:noreply, state}
  end

  @impl true
  def handle_info({:blackboard, _ref, Tuples.adf(robot, %{node: node} = adf)}, state)
      when node == node() do
    record(robot, adf)
    keep(robot, adf)
    {:noreply, state}
  end

  def handle_info(_message, state), do: {:noreply, state}

  defp record(robot, adf) do
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
  end

  defp keep(robot, adf) do
    black_box = Map.new(adf[:black_box] || %{})

    enabled =
      case black_box[:enabled] do
        nil -> Application.get_env(:tc_blackbox, :black_box_by_default, true)
        enabled -> enabled
      end

    if enabled do
      opts =
        black_box
        |> Map.delete(:enabled)
        |> Map.put(:activities, adf[:modules] || [])
        |> Enum.to_list()

      case ThinkingCap.BlackBox.keep(robot, opts) do
        {:ok, _pid} ->
          Logger.info(
            "black box of #{inspect(robot)} on, dumps into #{Path.expand(opts[:dir] || ".")}"
          )

        {:error, :already_keeping} ->
          :ok

        {:error, reason} ->
          Logger.error("black box of #{inspect(robot)} could not start: #{inspect(reason)}")
      end
    end
  end
end
