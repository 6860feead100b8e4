defmodule ThinkingCap.Dashboard.Foxglove.Connection do
  @moduledoc false
  # One connection to the Foxglove port: the handshake
  # (Foxglove.Handshake), then WebSocket frames (Foxglove.Frame) to and
  # from a Foxglove.Session. What every socket of the dashboard has, it
  # has too: frames over `max_frame` close it (1009); a message-rate budget
  # (over it, messages are dropped with a status error, and a client that
  # goes on flooding is closed, 1008); a send timeout (a client that stops
  # reading is dropped); a session that raises is logged (once a minute at
  # most) and the client gets a status error. It ends with its listener.

  use GenServer, restart: :temporary
  require Logger

  alias ThinkingCap.Dashboard.Core.RateBudget
  alias ThinkingCap.Dashboard.Foxglove.{Frame, Handshake, Messages, Session}

  @handshake_timeout 5_000
  @rate 100
  @burst 200
  @flood_close 2_000

  @doc "Starts a connection for `listener`; give it its socket with `serve/2`."
  @spec start(pid(), map()) :: GenServer.on_start()
  def start(listener, config), do: GenServer.start(__MODULE__, {listener, config})

  @doc "Hands the accepted `socket` to the connection `pid`."
  @spec serve(pid(), port()) :: :ok
  def serve(pid, socket) do
    case :gen_tcp.controlling_process(socket, pid) do
      :ok -> send(pid, {:socket, socket})
      {:error, _} -> GenServer.stop(pid)
    end

    :ok
  end

  @impl true
  def init({listener, config}) do
    Process.monitor(listener)

    {:ok,
     %{
       socket: nil,
       config: config,
       buffer: <<>>,
       fragments: nil,
       session: nil,
       budget: RateBudget.new(@rate, @burst),
       logged_at: nil
     }}
  end

  @impl true
  def handle_info({:socket, socket}, state) do
    state = %{state | socket: socket}

    with {:ok, request} <- Handshake.read(socket, @handshake_timeout),
         {:ok, subprotocol, _control} <- Handshake.check(request, state.config) do
      :ok =
        :inet.setopts(socket,
          packet: :raw,
          send_timeout: state.config.send_timeout,
          send_timeout_close: true
        )

      case :gen_tcp.send(socket, Handshake.accept(request, subprotocol)) do
        :ok ->
          {frames, state} = run(%{state | session: Session.new()}, :open, [Session.new()])
          :ok = :inet.setopts(socket, active: :once)
          send_frames(frames, state)

        {:error, _} ->
          {:stop, :normal, state}
      end
    else
      {:refuse, status, text} ->
        _ = :gen_tcp.send(socket, Handshake.refusal(status, text))
        :gen_tcp.close(socket)
        {:stop, :normal, state}

      {:error, _reason} ->
        _ = :gen_tcp.send(socket, Handshake.refusal(400, "a WebSocket upgrade is expected here"))
        :gen_tcp.close(socket)
        {:stop, :normal, state}
    end
  end

  def handle_info({:tcp, socket, data}, %{socket: socket} = state) do
    case frames(%{state | buffer: state.buffer <> data}) do
      {:ok, state} ->
        :ok = :inet.setopts(socket, active: :once)
        {:noreply, state}

      {:stop, state} ->
        {:stop, :normal, state}
    end
  end

  def handle_info({:tcp_closed, _socket}, state), do: {:stop, :normal, state}
  def handle_info({:tcp_error, _socket, _reason}, state), do: {:stop, :normal, state}

  def handle_info({:DOWN, _ref, :process, _listener, _reason}, state) do
    if state.session, do: _ = :gen_tcp.send(state.socket, Frame.close(1001, "going away"))
    {:stop, :normal, state}
  end

  # before the socket is open nothing is subscribed yet
  def handle_info(_message, %{session: nil} = state), do: {:noreply, state}

  def handle_info(message, state) do
    {frames, state} = run(state, :handle_info, [message, state.session])
    send_frames(frames, state)
  end

  @impl true
  def terminate(_reason, state) do
    if state.session, do: Session.close(state.session)
    :ok
  end

  # every whole frame in the buffer
  defp frames(state) do
    case Frame.parse(state.buffer, state.config.max_frame) do
      :more ->
        {:ok, state}

      {:error, code, reason} ->
        _ = :gen_tcp.send(state.socket, Frame.close(code, reason))
        {:stop, state}

      {:frame, fin, opcode, payload, rest} ->
        case frame(fin, opcode, payload, %{state | buffer: rest}) do
          {:ok, state} -> frames(state)
          {:stop, state} -> {:stop, state}
        end
    end
  end

  defp frame(_fin, :close, _payload, state) do
    _ = :gen_tcp.send(state.socket, Frame.close(1000, ""))
    {:stop, state}
  end

  defp frame(_fin, :ping, payload, state), do: sent(Frame.encode(:pong, payload), state)
  defp frame(_fin, :pong, _payload, state), do: {:ok, state}

  defp frame(true, opcode, payload, %{fragments: nil} = state) when opcode in [:text, :binary],
    do: message(opcode, payload, state)

  defp frame(false, opcode, payload, %{fragments: nil} = state) when opcode in [:text, :binary],
    do: {:ok, %{state | fragments: {opcode, payload}}}

  defp frame(fin, :continuation, payload, %{fragments: {opcode, sofar}} = state) do
    whole = sofar <> payload

    cond do
      byte_size(whole) > state.config.max_frame ->
        _ = :gen_tcp.send(state.socket, Frame.close(1009, "message over the limit"))
        {:stop, state}

      fin ->
        message(opcode, whole, %{state | fragments: nil})

      true ->
        {:ok, %{state | fragments: {opcode, whole}}}
    end
  end

  defp frame(_fin, _opcode, _payload, state) do
    _ = :gen_tcp.send(state.socket, Frame.close(1002, "unexpected continuation"))
    {:stop, state}
  end

  defp message(opcode, payload, state) do
    case RateBudget.admit(state.budget, now()) do
      {:ok, budget} ->
        fun = if opcode == :text, do: :handle_text, else: :handle_binary
        {frames, state} = run(%{state | budget: budget}, fun, [payload, state.session])

        case send_frames(frames, state) do
          {:noreply, state} -> {:ok, state}
          {:stop, :normal, state} -> {:stop, state}
        end

      {:drop, budget} ->
        state = %{state | budget: budget}

        if RateBudget.flooding?(budget, @flood_close) do
          Logger.warning("dashboard: a Foxglove client flooding the socket was closed")
          _ = :gen_tcp.send(state.socket, Frame.close(1008, "message flood"))
          {:stop, state}
        else
          case RateBudget.warn?(budget, 50) do
            {true, budget} ->
              warning = Messages.status(:error, "too many messages: dropped")
              sent(encode(warning), %{state | budget: budget})

            {false, budget} ->
              {:ok, %{state | budget: budget}}
          end
        end
    end
  end

  defp sent(iodata, state) do
    case :gen_tcp.send(state.socket, iodata) do
      :ok -> {:ok, state}
      {:error, _} -> {:stop, state}
    end
  end

  defp send_frames([], state), do: {:noreply, state}

  defp send_frames(frames, state) do
    case :gen_tcp.send(state.socket, Enum.map(frames, &encode/1)) do
      :ok -> {:noreply, state}
      # a client that stopped reading (the send timeout) or went away
      {:error, _} -> {:stop, :normal, state}
    end
  end

  defp encode({type, iodata}), do: Frame.encode(type, iodata)

  # the session's call; if it raises, the client gets a status error and
  # the session goes on as it was (logged once a minute at most, without
  # a stack trace)
  defp run(state, fun, args) do
    {frames, session} = apply(Session, fun, args)
    {frames, %{state | session: session}}
  rescue
    exception ->
      now = now()

      state =
        if state.logged_at == nil or now - state.logged_at >= 60_000 do
          Logger.error(
            "dashboard: Foxglove session #{fun} failed: " <> Exception.message(exception)
          )

          %{state | logged_at: now}
        else
          state
        end

      {[Messages.status(:error, "internal error: #{Exception.message(exception)}")], state}
  end

  defp now, do: System.monotonic_time(:millisecond)
end
