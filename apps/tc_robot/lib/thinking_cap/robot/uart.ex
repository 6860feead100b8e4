defmodule ThinkingCap.Robot.UART do
  @moduledoc """
  A serial line: one process owning one C port program
  (`apps/tc_robot/c_src/tc_uart.c`, built by the app's own compiler step
  into `priv/bin/tc_uart`), modelled on circuits_uart.

      {:ok, uart} = UART.start_link()
      UART.enumerate()
      #=> %{"/dev/ttyUSB0" => %{driver: "ftdi_sio", description: "FT232R USB UART", ...}}
      :ok = UART.open(uart, "/dev/ttyUSB0", speed: 115_200)
      :ok = UART.write(uart, <<128, 131>>)
      receive do
        {:tc_uart, "/dev/ttyUSB0", data} -> data
      end

  `open_pty/2` makes this UART the master end of a new pseudo-terminal
  pair and returns the slave's path, which another UART (or any program)
  opens: a serial line without hardware, for emulators and tests.

  ## Options (`open/3`, `open_pty/2`, `configure/2`)

    * `speed:` bits per second, default 9600 (1200..230400, and 460800,
      921600 and more where the C library defines them);
    * `data_bits:` 5..8, default 8;
    * `parity:` `:none` (default), `:even`, `:odd`;
    * `stop_bits:` 1 (default) or 2;
    * `flow_control:` `:none` (default), `:hardware` (RTS/CTS), `:software`
      (XON/XOFF);
    * `active:` `true` (default: data arrives as messages) or `false`
      (`read/2` it);
    * `framing:` a `ThinkingCap.Robot.UART.Framing` module or
      `{module, args}`, default `ThinkingCap.Robot.UART.Framing.None`;
    * `rx_framing_timeout:` ms after the last byte of an unfinished frame at
      which it is delivered as `{:partial, binary}`; 0 (default) never;
    * `rx_timestamps:` `true` to have each active-mode frame stamped with
      the moment the port program read its last bytes (see Messages);
      `false` (default).

  Options are checked before anything is done: a bad one (an unknown key,
  a value out of range, a speed the port program does not support) is
  `{:error, {:bad_option, key, value}}`. The line itself is always raw
  (no echo, no character translation), with `VMIN = VTIME = 0`, `CLOCAL`
  and `CREAD`. A setting the driver does not take is an error naming it
  (`{:einval, "tcsetattr /dev/ttyUSB0: the driver refused the data bits"}`),
  A pty has no wire and its Linux driver forces 8 data bits and no
  parity: on a pty any `data_bits` and `parity` are accepted and the line
  stays 8 bits without parity (what `settings/1` reports).

  ## Messages (active mode)

  To the controlling process (the process that called `open/3` or
  `open_pty/2`, or the one given to `controlling_process/2`):

    * `{:tc_uart, path, data}`: a binary as received (no framing) or each
      complete frame of the framing module;
    * `{:tc_uart, path, {:partial, binary}}`: an unfinished frame flushed
      by `rx_framing_timeout` (or given up by the framing, e.g. an
      over-long line);
    * with `rx_timestamps: true`, each of those two as
      `{:tc_uart, path, data, received_at}` instead: `received_at` is the
      `System.monotonic_time/0` at which the port program read the bytes
      that completed the frame. On a loaded machine the message may come
      milliseconds later; the stamp does not move with it;
    * `{:tc_uart, path, {:error, reason}}`: the line went away (`:eio`,
      `:closed`: a USB adapter unplugged, the master of a pty closed) or
      the port program died (`:port_died`, and it is restarted). The UART
      is closed after it; `open/3` may be called again.

  For a pty master, `path` is the slave's path. A pty master stays open
  while no process has its slave open (between the slave's closing and its
  reopening): only closing the master ends the pair. What the master
  writes meanwhile waits in the pty for the next process to open the slave.

  In passive mode the same frames (and the error) are queued for `read/2`.

  ## Errors

  A closed or never opened UART answers `{:error, :ebadf}` to `write/3`,
  `read/2`, `drain/1`, `flush/2`, `configure/2` and `settings/1`; an open
  one answers `{:error, :ealready}` to `open/3` and `open_pty/2`. Errors of
  the port program are `{:error, {code, message}}` with `code` an errno
  atom (`:enoent`, `:eacces`, `:ebusy`, `:etimedout`, ...) and `message`
  what failed, e.g. `{:enoent, "open /dev/ttyUSB0: No such file or directory"}`.
  A call pending when the port program dies gets `{:error, :port_died}`.
  """
  use GenServer
  require Logger

  alias ThinkingCap.Robot.UART.{Enumerator, Options}

  @type uart :: GenServer.server()
  @type frame :: binary() | {:partial, binary()} | term()
  @type reason :: atom() | {atom(), String.t()} | {:bad_option, term(), term()}

  @call_timeout 15_000

  @errors Map.new(
            ~w(enoent eacces eperm ebusy enxio enodev eio einval enotty eagain eisdir enotdir
               eloop enametoolong emfile enfile etimedout ebadf eintr enomem erofs epipe enospc
               eunknown closed)a,
            &{Atom.to_string(&1), &1}
          )

  @doc "Starts a UART process and its port program (`opts`: GenServer options, e.g. `name:`)."
  @spec start_link(GenServer.options()) :: GenServer.on_start()
  def start_link(opts \\ []), do: GenServer.start_link(__MODULE__, [], opts)

  @doc "Stops the UART (closing its line)."
  @spec stop(uart()) :: :ok
  def stop(uart), do: GenServer.stop(uart)

  @doc """
  The serial ports that exist (`/dev/ttyS*` with a UART behind them,
  `ttyUSB*`, `ttyACM*`, `ttyAMA*`, ..., and the `/dev/serial/by-id/*`
  links), each with what sysfs says when known: `driver`, `description`,
  and for USB adapters `manufacturer`, `vendor_id`, `product_id`,
  `serial_number` (links also `target`).
  """
  @spec enumerate() :: %{String.t() => map()}
  def enumerate, do: Enumerator.enumerate()

  @doc "Opens the serial port at `path` (see the module doc for `opts`)."
  @spec open(uart(), String.t(), keyword()) :: :ok | {:error, reason()}
  def open(uart, path, opts \\ []), do: GenServer.call(uart, {:open, path, opts}, @call_timeout)

  @doc """
  Makes this UART the master end of a new pseudo-terminal pair; returns the
  slave's path for another UART (or any program) to open. Options as for
  `open/3`; the line settings are applied to the slave side.
  """
  @spec open_pty(uart(), keyword()) :: {:ok, String.t()} | {:error, reason()}
  def open_pty(uart, opts \\ []), do: GenServer.call(uart, {:open_pty, opts}, @call_timeout)

  @doc "Changes options of the open line (any of the options of `open/3`)."
  @spec configure(uart(), keyword()) :: :ok | {:error, reason()}
  def configure(uart, opts), do: GenServer.call(uart, {:configure, opts}, @call_timeout)

  @doc """
  The line's settings as the driver reports them (`tcgetattr`): `speed`,
  `data_bits`, `parity`, `stop_bits`, `flow_control`.
  """
  @spec settings(uart()) :: {:ok, map()} | {:error, reason()}
  def settings(uart), do: GenServer.call(uart, :settings, @call_timeout)

  @doc """
  Writes `data` (with the framing's `add_framing/2` applied), waiting at
  most `timeout` ms (or `:infinity`) for the line to take all of it;
  `{:error, {:etimedout, message}}` if it did not (part may be written).
  """
  @spec write(uart(), iodata(), timeout()) :: :ok | {:error, reason()}
  def write(uart, data, timeout \\ 5000)
      when timeout == :infinity or (is_integer(timeout) and timeout >= 0) do
    GenServer.call(uart, {:write, data, timeout}, call_timeout(timeout))
  end

  @doc """
  Passive mode: the next frame (with no framing: every byte received so
  far), waiting up to `timeout` ms; `{:ok, ""}` when nothing came in time.
  `{:error, :einval}` in active mode.
  """
  @spec read(uart(), non_neg_integer()) :: {:ok, binary() | frame()} | {:error, reason()}
  def read(uart, timeout \\ 5000) when is_integer(timeout) and timeout >= 0,
    do: GenServer.call(uart, {:read, timeout}, call_timeout(timeout))

  @doc "Waits until everything written has been sent (`tcdrain`)."
  @spec drain(uart()) :: :ok | {:error, reason()}
  def drain(uart), do: GenServer.call(uart, :drain, 60_000)

  @doc "Discards received and not yet read bytes, bytes not yet sent, or both (`tcflush`)."
  @spec flush(uart(), :receive | :transmit | :both) :: :ok | {:error, reason()}
  def flush(uart, direction \\ :both) when direction in [:receive, :transmit, :both],
    do: GenServer.call(uart, {:flush, direction}, @call_timeout)

  @doc "Closes the line (a pty master: ends the pair). The UART may be opened again."
  @spec close(uart()) :: :ok
  def close(uart), do: GenServer.call(uart, :close, @call_timeout)

  @doc "Sends active-mode messages to `pid` from now on."
  @spec controlling_process(uart(), pid()) :: :ok
  def controlling_process(uart, pid) when is_pid(pid),
    do: GenServer.call(uart, {:controlling_process, pid})

  @doc false
  # The port program's OS pid (tests kill it).
  @spec os_pid(uart()) :: non_neg_integer() | nil
  def os_pid(uart), do: GenServer.call(uart, :os_pid)

  defp call_timeout(:infinity), do: :infinity
  defp call_timeout(ms), do: ms + @call_timeout

  ## Server

  @impl true
  def init([]) do
    Process.flag(:trap_exit, true)

    state = %{
      port: nil,
      speeds: [],
      pending: :queue.new(),
      line: nil,
      config: Options.defaults(),
      framing: nil,
      controller: nil,
      rx_queue: :queue.new(),
      reader: nil,
      rx_timer: nil,
      rx_at: nil,
      clock_offset: 0
    }

    case start_worker(state) do
      {:ok, state} -> {:ok, state}
      {:error, reason} -> {:stop, reason}
    end
  end

  @impl true
  def handle_call({:open, path, _opts}, _from, state) when not is_binary(path),
    do: {:reply, {:error, {:bad_option, :path, path}}, state}

  def handle_call({:open, _path, _opts}, _from, %{line: line} = state) when line != nil,
    do: {:reply, {:error, :ealready}, state}

  def handle_call({:open, path, opts}, from, state),
    do: open_line(state, <<?O>>, path, opts, from)

  def handle_call({:open_pty, _opts}, _from, %{line: line} = state) when line != nil,
    do: {:reply, {:error, :ealready}, state}

  def handle_call({:open_pty, opts}, from, state), do: open_line(state, <<?P>>, nil, opts, from)

  def handle_call(request, _from, %{line: nil} = state)
      when request in [:settings, :drain] or
             (is_tuple(request) and elem(request, 0) in [:configure, :write, :flush]),
      do: {:reply, {:error, :ebadf}, state}

  def handle_call({:configure, opts}, from, state) do
    with {:ok, config} <- Options.validate(opts, state.config, state.speeds),
         {:ok, framing} <- reinit_framing(config.framing, state) do
      command(state, <<?C, Options.encode(config)::binary>>, from, {:configure, config, framing})
    else
      error -> {:reply, error, state}
    end
  end

  def handle_call(:settings, from, state), do: command(state, <<?G>>, from, :settings)

  def handle_call({:write, data, timeout}, from, state) do
    {module, fstate} = state.framing

    with {:ok, framed, fstate} <- module.add_framing(data, fstate),
         {:ok, bytes} <- to_binary(framed) do
      ms = if timeout == :infinity, do: 0xFFFFFFFF, else: min(timeout, 0xFFFFFFFE)
      state = %{state | framing: {module, fstate}}
      command(state, <<?W, ms::32, bytes::binary>>, from, :write)
    else
      {:error, _} = error -> {:reply, error, state}
    end
  end

  def handle_call(:drain, from, state), do: command(state, <<?D>>, from, :drain)

  def handle_call({:flush, direction}, from, state) do
    code = %{receive: 0, transmit: 1, both: 2}[direction]
    command(state, <<?F, code>>, from, {:flush, direction})
  end

  def handle_call({:read, timeout}, from, state) do
    cond do
      not :queue.is_empty(state.rx_queue) ->
        {item, state} = take(state)
        {:reply, read_reply(item), state}

      state.line == nil ->
        {:reply, {:error, :ebadf}, state}

      state.config.active ->
        {:reply, {:error, :einval}, state}

      state.reader != nil ->
        {:reply, {:error, :ebusy}, state}

      true ->
        token = make_ref()
        Process.send_after(self(), {:read_timeout, token}, timeout)
        {:noreply, %{state | reader: {from, token}}}
    end
  end

  def handle_call(:close, _from, %{line: nil} = state), do: {:reply, :ok, state}
  def handle_call(:close, from, state), do: command(state, <<?X>>, from, :close)

  def handle_call({:controlling_process, pid}, _from, state),
    do: {:reply, :ok, %{state | controller: pid}}

  def handle_call(:os_pid, _from, state) do
    {:reply, with({:os_pid, pid} <- Port.info(state.port, :os_pid), do: pid), state}
  end

  @impl true
  def handle_info({port, {:data, frame}}, %{port: port} = state),
    do: {:noreply, handle_frame(frame, state)}

  def handle_info({port, {:exit_status, status}}, %{port: port} = state) do
    Logger.error("UART port program exited with status #{status}; restarting it")

    for {from, _op} <- :queue.to_list(state.pending),
        do: GenServer.reply(from, {:error, :port_died})

    state = %{state | pending: :queue.new()}
    state = if state.line, do: line_gone(state, :port_died), else: state

    case start_worker(%{state | port: nil}) do
      {:ok, state} -> {:noreply, state}
      {:error, reason} -> {:stop, reason, state}
    end
  end

  def handle_info({:read_timeout, token}, %{reader: {from, token}} = state) do
    GenServer.reply(from, {:ok, <<>>})
    {:noreply, %{state | reader: nil}}
  end

  def handle_info({:rx_framing_timeout, token}, %{rx_timer: {token, _}} = state) do
    {module, fstate} = state.framing
    {:ok, partials, fstate} = module.frame_timeout(fstate)
    state = %{state | framing: {module, fstate}, rx_timer: nil}
    {:noreply, Enum.reduce(partials, state, &deliver({:partial, &1}, &2))}
  end

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def terminate(_reason, state) do
    if state.port, do: Port.close(state.port)
    :ok
  catch
    _, _ -> :ok
  end

  ## Commands and replies

  # Replies come back in the order the commands went out.
  defp command(state, frame, from, op) do
    Port.command(state.port, frame)
    {:noreply, %{state | pending: :queue.in({from, op}, state.pending)}}
  rescue
    # the port program is dead; its exit status is on its way
    ArgumentError -> {:reply, {:error, :port_died}, state}
  end

  defp handle_frame(<<?R, ns::64, bytes::binary>>, %{line: line} = state) when line != nil do
    at = System.convert_time_unit(ns, :nanosecond, :native) + state.clock_offset
    received(bytes, %{state | rx_at: at})
  end

  defp handle_frame(<<?R, _::binary>>, state), do: state

  defp handle_frame(<<?L, code::binary>>, %{line: line} = state) when line != nil,
    do: line_gone(state, error_code(code))

  defp handle_frame(<<type, body::binary>>, state) when type in [?K, ?E] do
    result =
      case {type, body} do
        {?K, body} ->
          {:ok, body}

        {?E, <<n, code::binary-size(n), text::binary>>} ->
          {:error, {error_code(code), text}}

        _ ->
          {:error, {:eunknown, inspect(body)}}
      end

    case :queue.out(state.pending) do
      {{:value, {from, op}}, pending} ->
        {reply, state} = complete(op, result, %{state | pending: pending})
        GenServer.reply(from, reply)
        state

      {:empty, _} ->
        Logger.error("UART port program replied to no command: #{inspect(result)}")
        state
    end
  end

  defp handle_frame(frame, state) do
    Logger.error("unexpected frame from the UART port program: #{inspect(frame, limit: 20)}")
    state
  end

  defp complete({:open, path, config, framing, pid}, {:ok, body}, state) do
    path = path || body

    state = %{
      state
      | line: %{path: path, pty: body != ""},
        config: config,
        framing: framing,
        controller: pid,
        rx_queue: :queue.new(),
        # measured at each open: with time correction on, Erlang's clock
        # may drift from the OS's over a long run
        clock_offset: clock_offset()
    }

    {if(body == "", do: :ok, else: {:ok, path}), state}
  end

  defp complete({:configure, config, framing}, {:ok, _}, state) do
    state = %{state | config: config, framing: framing}

    if config.active do
      # frames queued in passive mode go out now, in order
      {items, state} = {:queue.to_list(state.rx_queue), %{state | rx_queue: :queue.new()}}
      {:ok, Enum.reduce(items, state, &deliver/2)}
    else
      {:ok, state}
    end
  end

  defp complete(:settings, {:ok, body}, state), do: {{:ok, Options.decode(body)}, state}

  defp complete({:flush, direction}, {:ok, _}, state) do
    {module, fstate} = state.framing
    state = %{state | framing: {module, module.flush(direction, fstate)}}

    if direction == :transmit,
      do: {:ok, state},
      else: {:ok, cancel_rx_timer(%{state | rx_queue: :queue.new()})}
  end

  defp complete(:close, _result, state) do
    state = cancel_rx_timer(%{state | line: nil, rx_queue: :queue.new()})

    case state.reader do
      {from, _} -> GenServer.reply(from, {:error, :ebadf})
      nil -> :ok
    end

    {:ok, %{state | reader: nil}}
  end

  defp complete(_op, {:ok, _}, state), do: {:ok, state}
  defp complete(_op, {:error, _} = error, state), do: {error, state}

  ## Receiving

  defp received(bytes, state) do
    {module, fstate} = state.framing
    {status, frames, fstate} = module.remove_framing(bytes, fstate)
    state = Enum.reduce(frames, %{state | framing: {module, fstate}}, &deliver/2)
    state = cancel_rx_timer(state)

    if status == :in_frame and state.config.rx_framing_timeout > 0 do
      token = make_ref()

      timer =
        Process.send_after(self(), {:rx_framing_timeout, token}, state.config.rx_framing_timeout)

      %{state | rx_timer: {token, timer}}
    else
      state
    end
  end

  defp cancel_rx_timer(%{rx_timer: {_token, timer}} = state) do
    Process.cancel_timer(timer)
    %{state | rx_timer: nil}
  end

  defp cancel_rx_timer(state), do: state

  # The line is gone: the owner hears it, the UART is closed.
  defp line_gone(state, reason) do
    state = deliver({:error, reason}, state)
    cancel_rx_timer(%{state | line: nil})
  end

  defp deliver(item, %{config: %{active: true}} = state) do
    cond do
      state.controller == nil ->
        :ok

      stamped?(item, state) ->
        send(state.controller, {:tc_uart, state.line.path, item, state.rx_at})

      true ->
        send(state.controller, {:tc_uart, state.line.path, item})
    end

    state
  end

  defp deliver(item, %{reader: {from, _token}} = state) do
    GenServer.reply(from, read_reply(item))
    %{state | reader: nil}
  end

  defp deliver(item, state), do: %{state | rx_queue: :queue.in(item, state.rx_queue)}

  defp stamped?({:error, _}, _state), do: false
  defp stamped?(_item, state), do: state.config.rx_timestamps and state.rx_at != nil

  # Erlang's monotonic time less CLOCK_MONOTONIC (which stamps the port
  # program's reads, and is the timing worker's clock), in native units
  defp clock_offset do
    System.monotonic_time() -
      System.convert_time_unit(ThinkingCap.Cycle.Clock.now_ns(), :nanosecond, :native)
  end

  defp read_reply({:error, _} = error), do: error
  defp read_reply(item), do: {:ok, item}

  # Passive read: one frame, or with no framing every byte queued.
  defp take(state) do
    {{:value, item}, queue} = :queue.out(state.rx_queue)

    case {state.framing, item} do
      {{ThinkingCap.Robot.UART.Framing.None, _}, bin} when is_binary(bin) ->
        {more, queue} = take_binaries(queue, [bin])
        {more, %{state | rx_queue: queue}}

      _ ->
        {item, %{state | rx_queue: queue}}
    end
  end

  defp take_binaries(queue, acc) do
    case :queue.peek(queue) do
      {:value, bin} when is_binary(bin) -> take_binaries(:queue.drop(queue), [bin | acc])
      _ -> {IO.iodata_to_binary(Enum.reverse(acc)), queue}
    end
  end

  ## Helpers

  # an open (a device path) or open_pty (a new pty pair: path nil) command
  defp open_line(state, op, path, opts, {pid, _} = from) do
    with {:ok, config} <- Options.validate(opts, Options.defaults(), state.speeds),
         {:ok, framing} <- init_framing(config.framing) do
      command(state, op <> Options.encode(config) <> (path || ""), from, {
        :open,
        path,
        config,
        framing,
        pid
      })
    else
      error -> {:reply, error, state}
    end
  end

  defp init_framing({module, args}) do
    case module.init(args) do
      {:ok, fstate} -> {:ok, {module, fstate}}
      {:error, _} = error -> error
      other -> {:error, {:bad_option, :framing, other}}
    end
  end

  # the same framing keeps its state (and buffered bytes)
  defp reinit_framing(framing, state) do
    if framing == state.config.framing, do: {:ok, state.framing}, else: init_framing(framing)
  end

  defp to_binary(iodata) do
    {:ok, IO.iodata_to_binary(iodata)}
  rescue
    ArgumentError -> {:error, {:bad_data, iodata}}
  end

  defp error_code(code), do: Map.get(@errors, code, :eunknown)

  defp start_worker(state) do
    path = Application.app_dir(:tc_robot, "priv/bin/tc_uart")
    port = Port.open({:spawn_executable, path}, [:binary, {:packet, 4}, :exit_status])

    receive do
      {^port, {:data, <<?H, speeds::binary>>}} ->
        {:ok, %{state | port: port, speeds: for(<<s::32 <- speeds>>, do: s)}}

      {^port, {:exit_status, status}} ->
        {:error, {:port_program_failed, status}}
    after
      5000 -> {:error, :port_program_silent}
    end
  end
end
