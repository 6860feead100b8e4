defmodule ThinkingCap.Dashboard.Foxglove.Listener do
  @moduledoc false
  # The Foxglove port's listener: accepts connections (between its own
  # messages, as Core.EstopListener does) and starts a
  # Foxglove.Connection for each, at most `max_connections` at once
  # (beyond, a 503 at once). The connections watch it: when it stops (the
  # dashboard stopping), they close (1001) and end.

  use GenServer
  require Logger

  alias ThinkingCap.Dashboard.Core.Acceptor
  alias ThinkingCap.Dashboard.Foxglove.{Connection, Handshake}

  @doc "Starts the listener on `config.foxglove_port` (0: a free port) of `config.host`."
  @spec start_link(map()) :: GenServer.on_start()
  def start_link(config), do: GenServer.start_link(__MODULE__, config, name: __MODULE__)

  @doc "The port it listens on; nil when it is not running."
  @spec port() :: :inet.port_number() | nil
  def port, do: Acceptor.port(__MODULE__)

  @doc "The open connections' processes."
  @spec connections() :: [pid()]
  def connections do
    case Process.whereis(__MODULE__) do
      nil -> []
      _pid -> GenServer.call(__MODULE__, :connections)
    end
  end

  @impl true
  def init(config) do
    extra = [packet_size: 16_384, nodelay: true]

    case Acceptor.listen(config.foxglove_port, config.host, extra, "Foxglove port") do
      {:ok, listen, port} -> {:ok, %{listen: listen, port: port, config: config, open: %{}}, 0}
      {:error, message} -> {:stop, message}
    end
  end

  @impl true
  def handle_call(:port, _from, state), do: {:reply, state.port, state, 0}
  def handle_call(:connections, _from, state), do: {:reply, Map.values(state.open), state, 0}

  # a timeout of 0 fires when the mailbox is empty: it accepts (waiting a
  # little) between its messages
  @impl true
  def handle_info(:timeout, state) do
    state =
      case Acceptor.accept(state.listen, "Foxglove port") do
        {:ok, socket} ->
          serve(socket, state)

        :none ->
          state

        :no_descriptor ->
          Logger.warning("dashboard: Foxglove port: no file descriptor left to accept with")
          Process.sleep(50)
          state
      end

    {:noreply, state, 0}
  end

  def handle_info({:DOWN, ref, :process, _, _}, state),
    do: {:noreply, %{state | open: Map.delete(state.open, ref)}, 0}

  def handle_info(_other, state), do: {:noreply, state, 0}

  defp serve(socket, state) do
    # the configuration as it is now (the token, public_view)
    config = ThinkingCap.Dashboard.config() || state.config

    if map_size(state.open) >= config.max_connections do
      _ = :gen_tcp.send(socket, Handshake.refusal(503, "too many connections, try again"))
      :gen_tcp.close(socket)
      state
    else
      {:ok, pid} = Connection.start(self(), config)
      :ok = Connection.serve(pid, socket)
      %{state | open: Map.put(state.open, Process.monitor(pid), pid)}
    end
  end
end
