defmodule ThinkingCap.Dashboard.Core.Socket do
  @moduledoc false
  # The yaws WebSocket callback module behind the page's `/ws` and the
  # rosbridge port. It owns what every socket needs, and hands each text
  # message to a handler module (the page's Session, rosbridge's Session):
  #
  #   * frames above `max_frame` bytes are refused by yaws (close 1009)
  #     before they are read;
  #   * a message-rate budget (`RateBudget`, a token bucket): messages over
  #     it are dropped with an error reply, and a client that goes on
  #     flooding (@flood_close drops without a pause) is closed (1008);
  #   * a send timeout: a browser that stops reading is dropped, so it never
  #     holds the process that serves it (nor anything upstream of it);
  #   * a handler that raises gets an error reply, and its error logged
  #     once a minute per client at most, without a stack trace; the
  #     socket stays open;
  #   * binary frames get an error reply.

  require Logger
  import ThinkingCap.Dashboard.Core.Records
  alias ThinkingCap.Dashboard.Core.RateBudget

  @typedoc "What a handler learns about its client."
  @type conn :: %{
          control: boolean(),
          query: %{String.t() => String.t()},
          peer: {:inet.ip_address(), :inet.port_number()} | nil,
          origin: String.t() | nil,
          config: map()
        }
  @type result :: {:reply, [iodata()], term()} | {:noreply, term()} | {:close, term()}

  @doc """
  Called in the socket's process before the handshake completes: set up
  state only. `handle_info(:open, state)` comes first once the socket is
  open; subscribe and start timers there (messages that arrive earlier are
  held until then).
  """
  @callback init(conn()) :: {:ok, term()} | {:error, term()}
  @callback handle_text(binary(), term()) :: result()
  @callback handle_info(term(), term()) :: result()
  @callback error_frame(message :: String.t()) :: iodata()
  @callback terminate(term(), term()) :: term()

  @rate 100
  @burst 200
  @flood_close 2_000
  @send_timeout 5_000

  @doc "The open sockets: `[{pid, handler}]`."
  @spec open_sockets() :: [{pid(), module()}]
  def open_sockets, do: Registry.lookup(ThinkingCap.Dashboard.Sockets, :socket)

  @doc "Closes every open socket (1001: going away)."
  @spec close_all() :: :ok
  def close_all do
    for {pid, _handler} <- open_sockets(),
        do: :yaws_api.websocket_close(pid, {1001, "going away"})

    :ok
  end

  @doc false
  def init([_arg, {handler, conn}]) do
    case handler.init(conn) do
      {:ok, hstate} ->
        {:ok, _} = Registry.register(ThinkingCap.Dashboard.Sockets, :socket, handler)

        {:ok,
         %{
           handler: handler,
           hstate: hstate,
           budget: RateBudget.new(@rate, @burst),
           open: false,
           held: [],
           logged_at: nil,
           send_timeout: conn.config[:send_timeout] || @send_timeout
         }}

      {:error, reason} ->
        {:error, reason}
    end
  end

  @doc false
  def handle_open(ws, state) do
    case ws_state(ws, :sock) do
      sock when is_port(sock) ->
        _ = :inet.setopts(sock, send_timeout: state.send_timeout, send_timeout_close: true)

      _ssl ->
        :ok
    end

    send(self(), :"$tc_socket_open")
    {:ok, state}
  end

  @doc false
  # a client may speak before the socket process has read its own "open"
  # message: open first, so the handler has set up what the text needs
  def handle_message({:text, _text} = message, %{open: false} = state) do
    case handle_info(:"$tc_socket_open", state) do
      {:reply, frames, state} -> merge(frames, handle_message(message, state))
      {:noreply, state} -> handle_message(message, state)
      closed -> closed
    end
  end

  def handle_message({:text, text}, state) do
    case RateBudget.admit(state.budget, now()) do
      {:ok, budget} ->
        call(%{state | budget: budget}, :handle_text, [text, state.hstate])

      {:drop, budget} ->
        if RateBudget.flooding?(budget, @flood_close) do
          Logger.warning("dashboard: a client flooding the socket was closed")
          {:close, {1008, "message flood"}, %{state | budget: budget}}
        else
          case RateBudget.warn?(budget, 50) do
            {true, budget} ->
              {:reply, [frame(state.handler.error_frame("too many messages: dropped"))],
               %{state | budget: budget}}

            {false, budget} ->
              {:noreply, %{state | budget: budget}}
          end
        end
    end
  end

  def handle_message({:binary, _data}, state),
    do: {:reply, [frame(state.handler.error_frame("binary frames are not understood"))], state}

  def handle_message({:close, _status, _reason}, state), do: {:close, :normal, state}

  def handle_message(_other, state), do: {:noreply, state}

  defp merge(frames, {:reply, more, state}), do: {:reply, frames ++ more, state}
  defp merge(frames, {:noreply, state}), do: {:reply, frames, state}
  defp merge(_frames, closed), do: closed

  @doc false
  def handle_info(:"$tc_socket_open", %{open: true} = state), do: {:noreply, state}

  def handle_info(:"$tc_socket_open", state) do
    state = %{state | open: true}

    Enum.reduce(Enum.reverse(state.held), call(state, :handle_info, [:open, state.hstate]), fn
      message, {:reply, frames, state} ->
        case call(state, :handle_info, [message, state.hstate]) do
          {:reply, more, state} -> {:reply, frames ++ more, state}
          {:noreply, state} -> {:reply, frames, state}
          closed -> closed
        end

      message, {:noreply, state} ->
        call(state, :handle_info, [message, state.hstate])

      _message, closed ->
        closed
    end)
    |> case do
      {:reply, frames, state} -> {:reply, frames, %{state | held: []}}
      {:noreply, state} -> {:noreply, %{state | held: []}}
      closed -> closed
    end
  end

  def handle_info(message, %{open: false} = state),
    do: {:noreply, %{state | held: [message | state.held]}}

  def handle_info(message, state), do: call(state, :handle_info, [message, state.hstate])

  @doc false
  def terminate(reason, state) do
    state.handler.terminate(reason, state.hstate)
  rescue
    _ -> :ok
  end

  defp call(state, fun, args) do
    case apply(state.handler, fun, args) do
      {:reply, frames, hstate} -> {:reply, Enum.map(frames, &frame/1), %{state | hstate: hstate}}
      {:noreply, hstate} -> {:noreply, %{state | hstate: hstate}}
      {:close, hstate} -> {:close, :normal, %{state | hstate: hstate}}
    end
  rescue
    exception ->
      # once a minute per client at most, and no stack trace: a client
      # sending the same bad message on and on must not fill the log
      now = now()

      state =
        if state.logged_at == nil or now - state.logged_at >= 60_000 do
          Logger.error(
            "dashboard: #{inspect(state.handler)}.#{fun} failed on a client's message: " <>
              Exception.message(exception)
          )

          %{state | logged_at: now}
        else
          state
        end

      {:reply,
       [frame(state.handler.error_frame("internal error: #{Exception.message(exception)}"))],
       state}
  end

  defp frame(iodata), do: {:text, IO.iodata_to_binary(iodata)}

  defp now, do: System.monotonic_time(:millisecond)
end
