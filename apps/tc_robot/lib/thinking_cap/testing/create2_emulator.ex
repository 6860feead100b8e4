defmodule ThinkingCap.Testing.Create2Emulator do
  @moduledoc """
  An iRobot Create 2 on a pseudo-terminal, for tests: it speaks the Open
  Interface (`ThinkingCap.Robot.Create2.Protocol`) on the master end of a
  pty pair (`ThinkingCap.Robot.UART.open_pty/2`), and a driver opens the
  slave end as if it were the robot's USB serial cable.

      {:ok, emu} = Create2Emulator.start_link(link: Path.join(tmp, "create2"))
      # ADF: params: [device: Path.join(tmp, "create2")]

  The slave's path changes with every pty (`/dev/pts/N`), so the emulator
  keeps a stable path for it, the `link:` symlink, the way udev's
  `/dev/serial/by-id/...` links name a USB adapter whatever its
  `/dev/ttyUSBn`. `unplug/1` closes the pty master (the driver's line gets
  an error) and removes the link; `replug/1` makes a new pty and points
  the link at it.

  The emulator and its UART run at high priority (the UART's port program
  at `SCHED_FIFO` 10 where the OS grants it), as hardware does not wait
  for the BEAM, and commands are stamped with the moment the UART's
  port program read them off the pty (`rx_timestamps: true`), not the
  later one at which the BEAM got round to them.

  ## What it implements

  Modes Off (until Start), Passive, Safe, Full; Start, Reset, Stop, Safe,
  Full, Power; Drive (velocity and radius, the special radii) and Drive
  Direct (ignored unless in Safe or Full; every one received is recorded
  with the `System.monotonic_time/0` at which it was read, for
  `commands/1`); Sensors, Query
  List, Stream (a frame every 15 ms with the packets asked for) and
  Pause/Resume Stream. The other opcodes are consumed with their data
  bytes and ignored. Commands are parsed byte by byte, so they may arrive
  split across reads.

  The wheels' motion is integrated from monotonic time: the pose (m, rad,
  from the origin), the encoder counts (508.8 per revolution of a 72 mm
  wheel, wrapping at 65536), distance and angle since they were last read.
  The wheel base is 235 mm. In Safe mode a wheel drop stops the motors and
  the robot reverts to Passive.

  ## Faults

  `corrupt/2` (the next frames with a wrong checksum), `truncate/2` (the
  next frames cut short), `garbage/2` (bytes on the line now), `bump/2`,
  `wheel_drop/2`, `unplug/1`, `replug/1`.
  """
  use GenServer

  require Logger

  alias ThinkingCap.Robot.{Kinematics, UART}
  alias ThinkingCap.Robot.Create2.Protocol

  @period_ms 15
  @wheel_base 235.0
  @counts_per_mm 508.8 / (:math.pi() * 72.0)
  @max_records 10_000

  # data bytes after each opcode (148, 149 and 140 have variable lengths)
  @arguments %{
    128 => 0,
    129 => 1,
    130 => 0,
    131 => 0,
    132 => 0,
    133 => 0,
    134 => 0,
    135 => 0,
    136 => 0,
    137 => 4,
    138 => 1,
    139 => 3,
    141 => 1,
    142 => 1,
    143 => 0,
    144 => 3,
    145 => 4,
    146 => 4,
    147 => 1,
    150 => 1,
    162 => 1,
    163 => 4,
    164 => 4,
    165 => 1,
    167 => 15,
    168 => 3,
    173 => 0,
    7 => 0
  }

  @typedoc "A recorded drive command."
  @type record :: %{
          at: integer(),
          command: {:drive_direct, integer(), integer()} | {:drive, integer(), integer()},
          applied: boolean()
        }

  ## API

  @doc """
  Starts an emulated robot on a new pty. Options: `link:` (required) the
  stable path made a symlink to the pty's slave; `name:` a GenServer name.
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts) do
    {name, opts} = Keyword.pop(opts, :name)
    GenServer.start_link(__MODULE__, opts, if(name, do: [name: name], else: []))
  end

  @doc "Stops the emulator (its pty and link go, also when its supervisor stops it)."
  @spec stop(GenServer.server()) :: :ok
  def stop(emu), do: GenServer.stop(emu)

  @doc "The stable path to open (the `link:` option)."
  @spec link(GenServer.server()) :: Path.t()
  def link(emu), do: GenServer.call(emu, :link)

  @doc """
  The robot now: `mode` (`:off`, `:passive`, `:safe`, `:full`), `left` and
  `right` wheel speeds (mm/s), `pose` `{x, y, theta}` (m, rad),
  `streaming?`, `packets` (streamed), `plugged?`, `left_counts`,
  `right_counts`, `bumps`, `wheel_drop`, `frames` (stream frames sent).
  """
  @spec state(GenServer.server()) :: map()
  def state(emu), do: GenServer.call(emu, :state)

  @doc "Every drive command received, oldest first (the last #{@max_records})."
  @spec commands(GenServer.server()) :: [record()]
  def commands(emu), do: GenServer.call(emu, :commands)

  @doc "The next `n` stream frames go out with a wrong checksum."
  @spec corrupt(GenServer.server(), pos_integer()) :: :ok
  def corrupt(emu, n) when is_integer(n) and n > 0, do: GenServer.call(emu, {:fault, :corrupt, n})

  @doc "The next `n` stream frames go out cut short (their first half only)."
  @spec truncate(GenServer.server(), pos_integer()) :: :ok
  def truncate(emu, n) when is_integer(n) and n > 0,
    do: GenServer.call(emu, {:fault, :truncate, n})

  @doc "Writes `bytes` on the line now, between frames."
  @spec garbage(GenServer.server(), binary()) :: :ok
  def garbage(emu, bytes) when is_binary(bytes), do: GenServer.call(emu, {:garbage, bytes})

  @doc "Presses the bumper: `:left`, `:right`, `:both`, or releases it: `:none`."
  @spec bump(GenServer.server(), :left | :right | :both | :none) :: :ok
  def bump(emu, side) when side in [:left, :right, :both, :none],
    do: GenServer.call(emu, {:bump, side})

  @doc "Drops (true) or lifts back (false) both wheels; in Safe mode a drop stops and goes Passive."
  @spec wheel_drop(GenServer.server(), boolean()) :: :ok
  def wheel_drop(emu, dropped) when is_boolean(dropped),
    do: GenServer.call(emu, {:wheel_drop, dropped})

  @doc "Pulls the cable: closes the pty master and removes the link."
  @spec unplug(GenServer.server()) :: :ok
  def unplug(emu), do: GenServer.call(emu, :unplug)

  @doc "Plugs the cable back: a new pty, the link pointed at its slave."
  @spec replug(GenServer.server()) :: :ok | {:error, term()}
  def replug(emu), do: GenServer.call(emu, :replug)

  ## GenServer

  @impl true
  def init(opts) do
    link = Keyword.fetch!(opts, :link)
    # hardware does not wait for the BEAM (see the moduledoc)
    Process.flag(:priority, :high)
    # stopped by a supervisor (ExUnit's start_supervised/1 too), terminate/2
    # must run: the link would otherwise stay, naming /dev/pts/N, which the
    # next pty made takes over, and whatever still opens the link (a driver
    # left running, a wire reopened) would reach that pty's owner
    Process.flag(:trap_exit, true)
    {:ok, uart} = UART.start_link(spawn_opt: [priority: :high])
    realtime(uart)

    state = %{
      uart: uart,
      link: link,
      plugged: false,
      buffer: <<>>,
      mode: :off,
      left: 0,
      right: 0,
      requested: {0, 0},
      pose: {0.0, 0.0, 0.0},
      left_mm: 0.0,
      right_mm: 0.0,
      distance: 0.0,
      angle: 0.0,
      at: System.monotonic_time(),
      received_at: nil,
      packets: [],
      streaming: false,
      bumps: :none,
      wheel_drop: false,
      corrupt: 0,
      truncate: 0,
      frames: 0,
      records: :queue.new(),
      count: 0
    }

    case plug(state) do
      {:ok, state} ->
        {:ok, _} = :timer.send_interval(@period_ms, :tick)
        {:ok, state}

      {:error, reason} ->
        {:stop, reason}
    end
  end

  @impl true
  def handle_call(:link, _from, state), do: {:reply, state.link, state}

  def handle_call(:state, _from, state) do
    state = advance(state)

    reply = %{
      mode: state.mode,
      left: state.left,
      right: state.right,
      pose: state.pose,
      streaming?: state.streaming,
      packets: state.packets,
      plugged?: state.plugged,
      left_counts: counts(state.left_mm),
      right_counts: counts(state.right_mm),
      bumps: state.bumps,
      wheel_drop: state.wheel_drop,
      frames: state.frames
    }

    {:reply, reply, state}
  end

  def handle_call(:commands, _from, state), do: {:reply, :queue.to_list(state.records), state}

  def handle_call({:fault, kind, n}, _from, state), do: {:reply, :ok, Map.put(state, kind, n)}

  def handle_call({:garbage, bytes}, _from, state) do
    send_bytes(state, bytes)
    {:reply, :ok, state}
  end

  def handle_call({:bump, side}, _from, state), do: {:reply, :ok, %{state | bumps: side}}

  def handle_call({:wheel_drop, dropped}, _from, state),
    do: {:reply, :ok, state |> advance() |> Map.put(:wheel_drop, dropped) |> safety()}

  def handle_call(:unplug, _from, %{plugged: false} = state), do: {:reply, :ok, state}

  def handle_call(:unplug, _from, state) do
    UART.close(state.uart)
    File.rm(state.link)
    {:reply, :ok, %{state | plugged: false, buffer: <<>>}}
  end

  def handle_call(:replug, _from, %{plugged: true} = state), do: {:reply, :ok, state}

  def handle_call(:replug, _from, state) do
    case plug(state) do
      {:ok, state} -> {:reply, :ok, state}
      {:error, reason} -> {:reply, {:error, reason}, state}
    end
  end

  @impl true
  def handle_info(:tick, state) do
    state = state |> advance() |> safety()

    state =
      if state.plugged and state.streaming and state.mode != :off,
        do: send_frame(state),
        else: state

    {:noreply, state}
  end

  def handle_info({:tc_uart, _path, {:error, reason}}, state) do
    Logger.debug("Create 2 emulator: pty master: #{inspect(reason)}")
    File.rm(state.link)
    {:noreply, %{state | plugged: false, buffer: <<>>}}
  end

  def handle_info({:tc_uart, _path, data, at}, %{plugged: true} = state) when is_binary(data) do
    # the wheels changed when the bytes came, not when the BEAM saw them
    state = advance(state, at)
    {buffer, state} = parse(state.buffer <> data, %{state | received_at: at})
    {:noreply, safety(%{state | buffer: buffer})}
  end

  # the pty master's process is gone: so is the robot
  def handle_info({:EXIT, uart, reason}, %{uart: uart} = state), do: {:stop, reason, state}

  def handle_info(_message, state), do: {:noreply, state}

  @impl true
  def terminate(_reason, state) do
    # the link first, so nothing opens the pty anew, then the pty itself
    File.rm(state.link)
    if Process.alive?(state.uart), do: UART.stop(state.uart)
    :ok
  catch
    :exit, _ -> :ok
  end

  ## The line

  # The port program reads the pty at a low real-time priority where the OS
  # grants it, as a robot's UART takes bytes off the wire whatever else
  # the machine runs; elsewhere it reads them as other programs let it.
  defp realtime(uart) do
    with chrt when is_binary(chrt) <- System.find_executable("chrt"),
         pid when is_integer(pid) <- UART.os_pid(uart),
         {_, 0} <- System.cmd(chrt, ["-f", "-p", "10", "#{pid}"], stderr_to_stdout: true) do
      :ok
    else
      other -> Logger.debug("Create 2 emulator: UART not real-time: #{inspect(other)}")
    end
  end

  defp plug(state) do
    with {:ok, slave} <-
           UART.open_pty(state.uart, speed: 115_200, active: true, rx_timestamps: true),
         :ok <- point_link(state.link, slave) do
      {:ok, %{state | plugged: true, buffer: <<>>}}
    end
  end

  # atomically, as udev re-points a by-id link
  defp point_link(link, target) do
    tmp = "#{link}.#{System.unique_integer([:positive])}"

    with :ok <- File.ln_s(target, tmp) do
      File.rename(tmp, link)
    end
  end

  defp send_bytes(%{plugged: true} = state, bytes), do: UART.write(state.uart, bytes)
  defp send_bytes(_state, _bytes), do: :ok

  ## Opcodes, byte by byte

  defp parse(<<>>, state), do: {<<>>, state}

  defp parse(<<op, rest::binary>> = buffer, state) do
    case arguments(op, rest) do
      {:ok, n} when byte_size(rest) >= n ->
        <<args::binary-size(n), rest::binary>> = rest
        parse(rest, execute(op, args, state))

      _wait ->
        {buffer, state}
    end
  end

  defp arguments(op, rest) when op in [148, 149] do
    case rest do
      <<n, _::binary>> -> {:ok, 1 + n}
      _ -> :more
    end
  end

  # Song: number, length, then a note and a duration per note
  defp arguments(140, rest) do
    case rest do
      <<_song, n, _::binary>> -> {:ok, 2 + 2 * n}
      _ -> :more
    end
  end

  # an unknown opcode is one byte, skipped
  defp arguments(op, _rest), do: {:ok, Map.get(@arguments, op, 0)}

  # Off: only Start (and Reset) are heard
  defp execute(128, _, state), do: %{stop_wheels(state) | mode: :passive}
  defp execute(7, _, state), do: %{stop_wheels(state) | mode: :off, streaming: false}
  defp execute(_op, _, %{mode: :off} = state), do: state

  defp execute(173, _, state), do: %{stop_wheels(state) | mode: :off, streaming: false}
  defp execute(op, _, state) when op in [130, 131], do: %{state | mode: :safe}
  defp execute(132, _, state), do: %{state | mode: :full}
  defp execute(133, _, state), do: %{stop_wheels(state) | mode: :passive}

  defp execute(137, <<v::16-signed, radius::16>>, state) do
    v = clamp(v)

    {left, right} =
      case radius do
        r when r in [0x8000, 0x7FFF] -> {v, v}
        1 -> {-v, v}
        0xFFFF -> {v, -v}
        r -> arc(v, signed16(r))
      end

    wheels(state, {:drive, v, signed16(radius)}, left, right)
  end

  defp execute(145, <<right::16-signed, left::16-signed>>, state),
    do: wheels(state, {:drive_direct, left, right}, clamp(left), clamp(right))

  defp execute(142, <<id>>, state) do
    {bytes, state} = packets_bytes([id], state)
    send_bytes(state, bytes)
    state
  end

  defp execute(149, <<_n, ids::binary>>, state) do
    {bytes, state} = packets_bytes(:binary.bin_to_list(ids), state)
    send_bytes(state, bytes)
    state
  end

  defp execute(148, <<_n, ids::binary>>, state) do
    ids = ids |> :binary.bin_to_list() |> Enum.filter(&Protocol.packet_size/1)
    %{state | packets: ids, streaming: ids != []}
  end

  defp execute(150, <<0>>, state), do: %{state | streaming: false}
  defp execute(150, <<_>>, state), do: %{state | streaming: state.packets != []}
  defp execute(_op, _args, state), do: state

  defp signed16(r) when r >= 0x8000, do: r - 0x10000
  defp signed16(r), do: r

  defp arc(_v, 0), do: {0, 0}

  defp arc(v, radius) do
    r = radius / 1
    {round(v * (r - @wheel_base / 2) / r), round(v * (r + @wheel_base / 2) / r)}
  end

  defp clamp(x), do: x |> max(-500) |> min(500)

  defp wheels(state, command, left, right) do
    applied = state.mode in [:safe, :full]
    state = record(state, command, applied)

    if applied,
      do: %{state | left: left, right: right, requested: {left, right}},
      else: state
  end

  defp record(state, command, applied) do
    records =
      :queue.in(%{at: state.received_at, command: command, applied: applied}, state.records)

    if state.count >= @max_records,
      do: %{state | records: :queue.drop(records)},
      else: %{state | records: records, count: state.count + 1}
  end

  defp stop_wheels(state), do: %{state | left: 0, right: 0, requested: {0, 0}}

  # Safe mode: a wheel drop stops the motors and reverts to Passive
  defp safety(%{mode: :safe, wheel_drop: true} = state),
    do: %{stop_wheels(state) | mode: :passive}

  defp safety(state), do: state

  ## Motion

  defp advance(state, at \\ System.monotonic_time()) do
    now = max(at, state.at)
    dt = System.convert_time_unit(now - state.at, :native, :microsecond) / 1.0e6
    v = (state.left + state.right) / 2
    w = (state.right - state.left) / @wheel_base

    %{
      state
      | at: now,
        pose: Kinematics.integrate(state.pose, {v / 1000, w}, dt),
        left_mm: state.left_mm + state.left * dt,
        right_mm: state.right_mm + state.right * dt,
        distance: state.distance + v * dt,
        angle: state.angle + w * dt
    }
  end

  defp counts(mm), do: mm |> Kernel.*(@counts_per_mm) |> floor() |> Integer.mod(65_536)

  ## Packets and frames

  defp send_frame(state) do
    {frame, state} = frame(state)

    cond do
      state.corrupt > 0 ->
        size = byte_size(frame) - 1
        <<body::binary-size(size), sum>> = frame
        send_bytes(state, body <> <<rem(sum + 1, 256)>>)
        %{state | corrupt: state.corrupt - 1, frames: state.frames + 1}

      state.truncate > 0 ->
        send_bytes(state, binary_part(frame, 0, div(byte_size(frame), 2)))
        %{state | truncate: state.truncate - 1, frames: state.frames + 1}

      true ->
        send_bytes(state, frame)
        %{state | frames: state.frames + 1}
    end
  end

  defp frame(state) do
    {values, state} = values(state.packets, state)
    {Protocol.stream_frame(values), state}
  end

  defp packets_bytes(ids, state) do
    ids = Enum.filter(ids, &Protocol.packet_size/1)
    {values, state} = values(ids, state)
    {IO.iodata_to_binary(for({id, value} <- values, do: Protocol.encode(id, value))), state}
  end

  # the packets' values; reading distance or angle takes what was read
  # off it (the fraction of a mm or a degree left stays for the next read)
  defp values(ids, state) do
    values = for id <- ids, do: {id, value(id, state)}

    state = if 19 in ids, do: %{state | distance: state.distance - value(19, state)}, else: state

    state =
      if 20 in ids,
        do: %{state | angle: state.angle - value(20, state) * :math.pi() / 180},
        else: state

    {values, state}
  end

  defp value(7, state) do
    %{
      bump_left: state.bumps in [:left, :both],
      bump_right: state.bumps in [:right, :both],
      wheel_drop_left: state.wheel_drop,
      wheel_drop_right: state.wheel_drop
    }
  end

  defp value(19, state), do: trunc(state.distance)
  defp value(20, state), do: trunc(state.angle * 180 / :math.pi())
  defp value(21, _state), do: 0
  defp value(22, _state), do: 15_600
  defp value(23, state), do: if(state.left != 0 or state.right != 0, do: -900, else: -200)
  defp value(24, _state), do: 26
  defp value(25, _state), do: 2_400
  defp value(26, _state), do: 3_000
  defp value(35, state), do: state.mode
  defp value(39, state), do: div(elem(state.requested, 0) + elem(state.requested, 1), 2)
  defp value(40, _state), do: 0
  defp value(41, state), do: elem(state.requested, 1)
  defp value(42, state), do: elem(state.requested, 0)
  defp value(43, state), do: counts(state.left_mm)
  defp value(44, state), do: counts(state.right_mm)
  defp value(_id, _state), do: 0
end
