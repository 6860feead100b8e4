defmodule ThinkingCap.Dashboard.Core.EstopListener do
  @moduledoc false
  # A listener that does one thing: engage E-stops. It is not the web
  # server, so a flood of connections to the page or to rosbridge (or the
  # web server being down) leaves it free:
  #
  #     curl -X POST http://127.0.0.1:4001/estop        # every robot
  #     curl -X POST http://127.0.0.1:4001/estop/r1     # one robot
  #
  # Engaging an E-stop needs no token (as on the page: anyone who sees the
  # robot may stop it); releasing one is not offered here. Its own flood
  # cannot block it either: at most @max_open connections at once, each
  # given @read_timeout ms to send its request; beyond the cap a
  # connection gets a 503 at once and is closed. Nor can running out of
  # file descriptors: it holds @spares spare ones (/dev/null open), and
  # gives them up one at a time to accept when the node has no other left
  # (another part of the node may take a freed descriptor first), then
  # accepts until a descriptor is free.

  use GenServer
  require Logger

  alias ThinkingCap.Dashboard.Control
  alias ThinkingCap.Dashboard.Core.Acceptor

  @max_open 16
  @read_timeout 1_000
  @max_headers 32
  # how long a connection may wait for a descriptor when the node has none
  @spare_wait 2_000
  # descriptors held in reserve, for when another part of the node takes
  # a freed one first (see accept_on_spare)
  @spares 4
  # ms between turns while the node has no descriptor and nobody connects
  @idle_turn 5

  @doc "Starts the listener on `estop_port` (0: a free port) of `host`."
  @spec start_link(%{host: String.t(), estop_port: :inet.port_number()}) :: GenServer.on_start()
  def start_link(opts), do: GenServer.start_link(__MODULE__, opts, name: __MODULE__)

  @doc "The port it listens on; nil when it is not running."
  @spec port() :: :inet.port_number() | nil
  def port, do: Acceptor.port(__MODULE__)

  @impl true
  def init(%{host: host, estop_port: port}) do
    case Acceptor.listen(port, host, [], "E-stop port") do
      {:ok, listen, port} ->
        {:ok, %{listen: listen, port: port, open: %{}, spares: refill([])}, 0}

      {:error, message} ->
        {:stop, message}
    end
  end

  @impl true
  def handle_call(:port, _from, state), do: {:reply, state.port, state, 0}

  # a timeout of 0 fires when the mailbox is empty: the listener accepts
  # (waiting a little) between its messages, which always get their turn
  @impl true
  def handle_info(:timeout, state) do
    # spares given up when descriptors ran out come back once they are free
    state =
      if length(state.spares) < @spares, do: %{state | spares: refill(state.spares)}, else: state

    state =
      case Acceptor.accept(state.listen, "E-stop port") do
        {:ok, socket} -> serve(socket, state)
        :none -> state
        # no descriptor left: a spare one serves this connection
        :no_descriptor -> accept_on_spare(state)
      end

    {:noreply, state, 0}
  end

  def handle_info({:DOWN, ref, :process, _, _}, state),
    do: {:noreply, %{state | open: Map.delete(state.open, ref)}, 0}

  def handle_info(_other, state), do: {:noreply, state, 0}

  defp spare do
    case File.open("/dev/null", [:read]) do
      {:ok, file} -> file
      {:error, _} -> nil
    end
  end

  # A spare descriptor, closed, is free for the next one the node opens,
  # and that may be another part of it (the web server's watchdog,
  # restarting yaws, takes descriptors and keeps them for seconds). And
  # Linux refuses an accept for want of a descriptor whether or not a
  # connection waits, so while the node is out of them the listener comes
  # here at every turn. So it closes one spare and accepts without
  # waiting: nobody there, it takes the spare back at once (the
  # descriptor was free for microseconds, not for an accept's 200 ms, in
  # which yaws took it: one run in five of the descriptor fault test lost
  # every spare that way, then its E-stop request); a connection there,
  # it serves it; the descriptor taken meanwhile, it closes the next
  # spare. With none left it accepts until a descriptor is free, up to
  # @spare_wait ms: a connection waits for the next free one, and never
  # for the node to free many.
  defp accept_on_spare(state) do
    deadline = System.monotonic_time(:millisecond) + @spare_wait

    accept = fn
      :now -> Acceptor.accept(state.listen, "E-stop port", 0)
      :wait -> Acceptor.accept(state.listen, "E-stop port")
    end

    {accepted, spares} = accept_releasing(accept, state.spares, deadline)

    case accepted do
      # served here, not in a process of its own: descriptors are short
      {:ok, socket} -> handle_here(socket)
      # nobody came: the loop turns again soon, not at once
      :none -> Process.sleep(@idle_turn)
    end

    %{state | spares: refill(spares)}
  end

  @doc false
  # The spares given up for one connection (accept_on_spare): closes one
  # and calls accept.(:now) (no wait) until a connection or nobody is
  # there; :no_descriptor means another part of the node took the
  # descriptor just freed, so the next spare goes. With none left,
  # accept.(:wait) (an accept's usual wait) until a descriptor is free
  # or `deadline`. Returns what the last accept gave and the spares
  # still held. (Public for its test, which stands in for accept and
  # for the descriptor's thief.)
  @spec accept_releasing((:now | :wait -> term()), [File.io_device()], integer()) ::
          {{:ok, :gen_tcp.socket()} | :none, [File.io_device()]}
  def accept_releasing(accept, [spare | rest], deadline) do
    File.close(spare)

    case accept.(:now) do
      :no_descriptor -> accept_releasing(accept, rest, deadline)
      accepted_or_none -> {accepted_or_none, rest}
    end
  end

  def accept_releasing(accept, [], deadline), do: {accept_when_free(accept, deadline), []}

  # Whatever goes wrong with a request served in the listener itself must
  # not take the listener down: restarted with no descriptor left, it
  # could not listen again.
  defp handle_here(socket) do
    handle(socket)
  catch
    kind, reason ->
      Logger.error(
        "dashboard: E-stop port: a request failed: " <>
          Exception.format(kind, reason, __STACKTRACE__)
      )

      :gen_tcp.close(socket)
  end

  # as many spares as @spares, or as the node's descriptors allow
  defp refill(spares) do
    if length(spares) >= @spares do
      spares
    else
      case spare() do
        nil -> spares
        file -> refill([file | spares])
      end
    end
  end

  defp accept_when_free(accept, deadline) do
    case accept.(:wait) do
      :no_descriptor ->
        if System.monotonic_time(:millisecond) < deadline do
          Process.sleep(5)
          accept_when_free(accept, deadline)
        else
          :none
        end

      accepted_or_none ->
        accepted_or_none
    end
  end

  defp serve(socket, state) do
    state = forget_ended(state)

    if map_size(state.open) >= @max_open do
      reply(socket, 503, "busy: too many connections to the E-stop port, try again\n")
      state
    else
      {pid, ref} = spawn_monitor(fn -> receive(do: (:go -> handle(socket))) end)

      case :gen_tcp.controlling_process(socket, pid) do
        :ok ->
          send(pid, :go)
          %{state | open: Map.put(state.open, ref, pid)}

        {:error, _} ->
          Process.exit(pid, :kill)
          :gen_tcp.close(socket)
          state
      end
    end
  end

  # the connections that ended while the listener waited in accept
  defp forget_ended(state) do
    receive do
      {:DOWN, ref, :process, _, _} -> forget_ended(%{state | open: Map.delete(state.open, ref)})
    after
      0 -> state
    end
  end

  defp handle(socket) do
    deadline = System.monotonic_time(:millisecond) + @read_timeout

    case read_request(socket, deadline) do
      {:ok, method, path} -> respond(socket, method, path)
      {:error, :bad_request} -> reply(socket, 400, "bad request\n")
      {:error, _closed_or_slow} -> :gen_tcp.close(socket)
    end
  end

  defp read_request(socket, deadline) do
    case recv(socket, deadline) do
      {:ok, {:http_request, method, {:abs_path, path}, _version}} ->
        with :ok <- skip_headers(socket, deadline, @max_headers), do: {:ok, method, path}

      {:ok, _other} ->
        {:error, :bad_request}

      error ->
        error
    end
  end

  defp skip_headers(_socket, _deadline, 0), do: {:error, :bad_request}

  defp skip_headers(socket, deadline, left) do
    case recv(socket, deadline) do
      {:ok, :http_eoh} -> :ok
      {:ok, {:http_header, _, _, _, _}} -> skip_headers(socket, deadline, left - 1)
      {:ok, _other} -> {:error, :bad_request}
      error -> error
    end
  end

  defp recv(socket, deadline) do
    case deadline - System.monotonic_time(:millisecond) do
      left when left > 0 -> :gen_tcp.recv(socket, 0, left)
      _ -> {:error, :timeout}
    end
  end

  defp respond(socket, :POST, "/estop"), do: engage(socket, Control.robots())

  defp respond(socket, :POST, "/estop/" <> name) do
    case Control.robot(name) do
      {:ok, robot} -> engage(socket, [robot])
      {:error, message} -> reply(socket, 404, message <> "\n")
    end
  end

  defp respond(socket, _method, "/estop" <> _),
    do: reply(socket, 405, "POST /estop (every robot) or POST /estop/NAME (one robot)\n")

  defp respond(socket, _method, _path),
    do: reply(socket, 404, "this port only engages E-stops: POST /estop or /estop/NAME\n")

  defp engage(socket, []), do: reply(socket, 404, "no robot is running here\n")

  defp engage(socket, robots) do
    Enum.each(robots, &Control.estop(&1, :estop_port))
    Logger.warning("dashboard: E-stop engaged on the E-stop port for #{inspect(robots)}")
    reply(socket, 200, "E-stop engaged: #{Enum.join(robots, ", ")}\n")
  end

  defp reply(socket, status, body) do
    reason = %{200 => "OK", 400 => "Bad Request", 404 => "Not Found", 405 => "Method Not Allowed"}

    _ =
      :gen_tcp.send(socket, [
        "HTTP/1.1 #{status} #{Map.get(reason, status, "Service Unavailable")}\r\n",
        "content-type: text/plain\r\ncontent-length: #{byte_size(body)}\r\n",
        "connection: close\r\n\r\n",
        body
      ])

    :gen_tcp.close(socket)
  end
end
