defmodule ThinkingCap.Dashboard.Core.Watchdog do
  @moduledoc false
  # Keeps the web server up. yaws exits for good when something kills it
  # often enough (running out of file descriptors makes its acceptor exit,
  # and its supervisor gives up): then the E-stop button and teleoperation
  # are gone while the robot drives on. The watchdog notices it two ways,
  # at once when the web server (Core.WebServer, which ends when any of
  # yaws' processes dies) goes down and within a few seconds
  # when a listener stops accepting, and starts yaws again on the same
  # ports, retrying each second until it is back.

  use GenServer
  require Logger

  alias ThinkingCap.Dashboard.Core.{WebServer, Yaws}

  @probe_every 1_000
  @probe_timeout 500
  # consecutive failed probes before a restart (a flood may make one fail)
  @probe_failures 5

  @doc "Starts the watchdog over `servers` (as given to `Yaws.start/2`, ports bound) and `limits`."
  @spec start_link({[map()], map()}) :: GenServer.on_start()
  def start_link({servers, limits}), do: GenServer.start_link(__MODULE__, {servers, limits})

  @doc "How often the watchdog has restarted the web server."
  @spec restarts(pid()) :: non_neg_integer()
  def restarts(pid), do: GenServer.call(pid, :restarts)

  @impl true
  def init({servers, limits}) do
    Process.send_after(self(), :probe, @probe_every)
    {:ok, %{servers: servers, limits: limits, monitor: monitor(), failures: 0, restarts: 0}}
  end

  @impl true
  def handle_call(:restarts, _from, state), do: {:reply, state.restarts, state}

  @impl true
  def handle_info({:DOWN, ref, :process, _, reason}, %{monitor: ref} = state) do
    Logger.warning("dashboard: the web server went down (#{inspect(reason)}), restarting it")
    {:noreply, restart(%{state | monitor: nil})}
  end

  def handle_info({:DOWN, _ref, :process, _, _}, state), do: {:noreply, state}

  def handle_info(:probe, state) do
    Process.send_after(self(), :probe, @probe_every)

    cond do
      state.monitor == nil ->
        {:noreply, restart(state)}

      Enum.all?(state.servers, &accepting?/1) ->
        {:noreply, %{state | failures: 0}}

      state.failures + 1 >= @probe_failures ->
        Logger.warning("dashboard: a listener stopped accepting, restarting the web server")
        {:noreply, restart(state)}

      true ->
        {:noreply, %{state | failures: state.failures + 1}}
    end
  end

  defp restart(state) do
    if state.monitor, do: Process.demonitor(state.monitor, [:flush])
    Yaws.stop()

    case Yaws.start(state.servers, state.limits) do
      {:ok, _ports} ->
        Logger.notice("dashboard: the web server is back")
        %{state | monitor: monitor(), failures: 0, restarts: state.restarts + 1}

      {:error, reason} ->
        # tried again at the next probe
        Logger.warning("dashboard: the web server did not start again: #{inspect(reason)}")
        %{state | monitor: nil, failures: 0}
    end
  end

  defp monitor do
    case WebServer.whereis() do
      nil -> nil
      pid -> Process.monitor(pid)
    end
  end

  defp accepting?(server) do
    case :gen_tcp.connect(Yaws.ip(server.host), server.port, [active: false], @probe_timeout) do
      {:ok, socket} ->
        :gen_tcp.close(socket)
        true

      {:error, _} ->
        false
    end
  end
end
