defmodule ThinkingCap.Robot.Create2 do
  @moduledoc """
  The iRobot Create 2 (Roomba 600 based) over its serial Open Interface: a
  `ThinkingCap.Robot` driver. Put it in the ADF in place of the simulated
  robot:

      base: [module: ThinkingCap.Robot.Create2, activity: :periodic, period: 0.01,
             deadline: 0.003, fallback: :stop, params: [device: "/dev/ttyUSB0"]]

  ## Params

    * `device` (required) - the serial port, e.g. `/dev/ttyUSB0` or a
      stable `/dev/serial/by-id/...` link;
    * `speed` - baud rate, default 115200 (the OI's default);
    * `mode` - `:safe` (default: a cliff or wheel drop stops the motors
      and the robot reverts to Passive) or `:full` (no safety features);
    * `reconnect_every` - seconds between attempts to reopen a lost
      line, default 0.5;
    * `wire` - who writes the motion commands on the line: `:worker` (the
      default) hands the command path to the timing worker, which writes
      each cycle's Drive Direct and, in the very cycle a result is late,
      the base module dies or the BEAM goes, Drive Direct 0 0
      (`ThinkingCap.Robot`'s `wire/1`); `:driver` writes them from
      `drive/2`.

  The robot's RDF must describe a differential drive: its `wheel_radius`
  and `wheel_separation` turn commands into wheel speeds and encoder
  counts into odometry (a Create 2: 0.036 and 0.235).

  ## On the line

  `open/2` opens the line (`ThinkingCap.Robot.UART`, 115200 8N1), sends
  Start, the mode, and Stream of packets #{inspect([7, 19, 20, 22, 23, 25, 26, 35, 43, 44])}
  (bumps and wheel drops, distance, angle, voltage, current, charge,
  capacity, OI mode, left and right encoder counts): a frame every 15 ms,
  cut and checked by `ThinkingCap.Robot.Create2.Framing`. Motion commands
  become Drive Direct (`encode_command/2`). `close/2` pauses the stream,
  stops the wheels and sends Stop.

  ## Readings

  Named after the RDF's sensors of type `:odometry` and `:bumper` (default
  `:odometry` and `:bumper`):

    * odometry, every frame: `%{pose: {x, y, theta}, v:, w:, twist:,
      left_counts:, right_counts:, stamp:}`, dead reckoning from the
      encoder counts (`ThinkingCap.Robot.Create2.Odometry`) in the frame
      where the driver started; `stamp` (s, `System.monotonic_time/0`'s
      clock) is when the UART's port program read the frame off the line,
      so a frame the BEAM took late does not bend the velocities;
    * bumper, on change and once a second: `%{pressed:, left:, right:,
      wheel_drop:}`;
    * `:battery`, once a second: `%{voltage:, current:, charge:, capacity:,
      percent:}` (V, A, Ah, Ah, 0-100);
    * `:link`, on change (connected, OI mode) and once a second:
      `%{connected:, device:, frames:, rejected:, garbage_bytes:,
      odometry_jumps:, mode:, streaming:}`; `frames` counts the valid
      stream frames, `rejected` the refused ones (bad checksum, bad
      length, truncated), `garbage_bytes` the bytes outside any frame, and
      `odometry_jumps` the encoder steps no wheel could make (not
      integrated).

  ## Faults

  Nothing the robot sends can crash the driver: bad frames are counted
  (and logged at debug level). A lost line (unplugged cable) publishes
  `connected: false` at once and the driver tries to reopen the device
  every `reconnect_every`; when it is back it sends Start, the mode and
  Stream again, and the last applied command (the base applies `:stop`
  when commands go stale, so this is never an old order). When the stream
  stops while the line is up (the robot was reset or switched off and on)
  for a second, the driver sends Start, the mode and Stream again. If the
  robot fell back to Passive (a wheel drop in Safe mode), the mode is
  re-entered with the next motion command, not before.
  """
  use ThinkingCap.Robot

  require Logger

  alias ThinkingCap.Robot.{Description, Kinematics, UART}
  alias ThinkingCap.Robot.Create2.{Framing, Odometry, Protocol}

  @packets [7, 19, 20, 22, 23, 25, 26, 35, 43, 44]
  # a stream frame of them: header, length, the packets, checksum
  @frame_bytes Protocol.stream_length(@packets) + 3
  @max_wheel_speed 500
  @publish_every_ms 1000
  @stale_stream_ms 1000

  @doc "The sensor packets the driver streams."
  @spec packets() :: [Protocol.packet_id()]
  def packets, do: @packets

  @doc """
  The bytes sent to the robot for a motion command: Drive Direct with
  each wheel's speed in mm/s, from the description's differential
  kinematics (`{:velocity, v, omega}` through
  `ThinkingCap.Robot.Kinematics.inverse/2`, `{:wheels, left, right}` in
  rad/s times the wheel radius). When a wheel would exceed the OI's 500
  mm/s both are scaled down together, keeping the curvature. `:stop` is
  Drive Direct 0 0. Anything else, or a drive that is not differential,
  is `{:error, reason}`.
  """
  @spec encode_command(ThinkingCap.Robot.command(), Description.t()) ::
          binary() | {:error, term()}
  def encode_command(command, %Description{kinematics: %Kinematics.Differential{} = k}) do
    case command do
      :stop ->
        Protocol.drive_direct(0, 0)

      {:velocity, v, w} when is_number(v) and is_number(w) ->
        {:wheels, l, r} = Kinematics.inverse(k, {v, w})
        wheels(l, r, k)

      {:wheels, l, r} when is_number(l) and is_number(r) ->
        wheels(l, r, k)

      other ->
        {:error, {:unsupported_command, other}}
    end
  end

  def encode_command(_command, %Description{}), do: {:error, :not_differential}

  defp wheels(l, r, k) do
    left = l * k.wheel_radius * 1000
    right = r * k.wheel_radius * 1000
    fastest = max(abs(left), abs(right))
    scale = if fastest > @max_wheel_speed, do: @max_wheel_speed / fastest, else: 1.0
    Protocol.drive_direct(left * scale, right * scale)
  end

  ## ThinkingCap.Robot

  @impl true
  def open(%Description{} = description, context) do
    params = context.params

    with {:ok, device} <- device(params[:device]),
         {:ok, mode} <- mode(Keyword.get(params, :mode, :safe)),
         %Kinematics.Differential{} = k <- description.kinematics do
      state = %{
        robot: context.robot,
        description: description,
        device: device,
        speed: Keyword.get(params, :speed, 115_200),
        mode: mode,
        wire: Keyword.get(params, :wire, :worker),
        reconnect_ms: round(Keyword.get(params, :reconnect_every, 0.5) * 1000),
        names: sensor_names(description),
        uart: nil,
        connected: false,
        odometry: Odometry.new(k.wheel_radius, k.wheel_separation),
        oi_mode: nil,
        wheel_drop: false,
        bumper: nil,
        battery: nil,
        frames: 0,
        rejected: 0,
        garbage_bytes: 0,
        lost: 0,
        last_frame_at: nil,
        received_at: nil,
        restarted_at: nil,
        published_at: nil,
        published_link: nil,
        command: :stop
      }

      {:ok, uart} = UART.start_link([])
      state = %{state | uart: uart}

      case connect(state) do
        {:ok, state} ->
          {:ok, state}

        {:error, reason, state} ->
          UART.stop(state.uart)
          {:error, {:open, device, reason}}
      end
    else
      {:error, _} = error -> error
      _kinematics -> {:error, "the Create 2 is a differential drive; the RDF says otherwise"}
    end
  end

  defp device(path) when is_binary(path) and path != "", do: {:ok, path}

  defp device(other),
    do: {:error, "device: expected the serial port's path, got #{inspect(other)}"}

  defp mode(mode) when mode in [:safe, :full], do: {:ok, mode}
  defp mode(other), do: {:error, "mode: expected :safe or :full, got #{inspect(other)}"}

  defp sensor_names(description) do
    named = fn type, default ->
      Enum.find_value(description.sensors, default, &(&1.type == type and &1.name))
    end

    %{odometry: named.(:odometry, :odometry), bumper: named.(:bumper, :bumper)}
  end

  # The timing worker owns the command path (param `wire: :worker`, the
  # default): it writes each cycle's Drive Direct itself, and Drive Direct
  # 0 0 in the very cycle a result is late, the base module dies or the
  # BEAM goes. `wire: :driver` leaves the writing to drive/2. Nil while
  # the line is lost: once it is back (maybe another tty behind the same
  # path, which the worker does not reopen by itself) the base attaches
  # the wire again.
  @impl true
  def wire(%{wire: :worker, connected: true} = state),
    do: {state.device, Protocol.drive_direct(0, 0)}

  def wire(_state), do: nil

  @impl true
  def wire_command(command, state) do
    case encode_command(command, state.description) do
      {:error, _reason} ->
        Protocol.drive_direct(0, 0)

      bytes ->
        # back from Passive (a wheel drop in Safe mode) with a new command
        if state.oi_mode == :passive and command != :stop and not state.wheel_drop,
          do: [Protocol.mode(state.mode), bytes],
          else: bytes
    end
  end

  @impl true
  def drive(command, %{connected: false} = state), do: {:ok, %{state | command: command}}

  def drive(command, state) do
    case encode_command(command, state.description) do
      {:error, reason} ->
        {:error, reason, state}

      bytes ->
        # back from Passive (a wheel drop in Safe mode) with a new command
        reenter =
          if state.oi_mode == :passive and command != :stop and not state.wheel_drop,
            do: Protocol.mode(state.mode),
            else: <<>>

        write(state, [reenter, bytes])
        {:ok, %{state | command: command}}
    end
  end

  @impl true
  def handle_data({:tc_uart, path, data, received_at}, state) do
    seconds = System.convert_time_unit(received_at, :native, :microsecond) / 1.0e6
    handle_data({:tc_uart, path, data}, %{state | received_at: seconds})
  end

  def handle_data({:tc_uart, _path, data}, state) do
    line(data, state)
  rescue
    # a last guard: whatever the robot sends, the driver keeps going
    e ->
      Logger.error("#{inspect(state.robot)}: Create 2 data #{inspect(data)}: #{inspect(e)}")
      {[], state}
  end

  def handle_data({:tc_create2, :reconnect}, %{connected: true} = state), do: {[], state}

  def handle_data({:tc_create2, :reconnect}, state) do
    case connect(state) do
      {:ok, state} ->
        Logger.info("#{inspect(state.robot)}: Create 2 back on #{state.device}")
        write(state, encode_command(state.command, state.description))
        link(state, true)

      {:error, _reason, state} ->
        schedule_reconnect(state)
        {[], state}
    end
  end

  def handle_data(_message, state), do: {[], state}

  @impl true
  def poll(state) do
    now = now_ms()
    state = restart_stale_stream(state, now)

    if state.published_at == nil or now - state.published_at >= @publish_every_ms do
      readings =
        [battery_reading(state), bumper_reading(state)]
        |> Enum.reject(&is_nil/1)

      {link, state} = link(state, true)
      {readings ++ link, %{state | published_at: now}}
    else
      {[], state}
    end
  end

  @impl true
  def close(_reason, state) do
    if state.connected do
      write(state, [Protocol.pause_stream(), Protocol.drive_direct(0, 0), Protocol.stop()])
    end

    if state.uart && Process.alive?(state.uart) do
      UART.close(state.uart)
      UART.stop(state.uart)
    end

    :ok
  catch
    :exit, _ -> :ok
  end

  ## The line

  defp connect(state) do
    opts = [
      speed: state.speed,
      data_bits: 8,
      parity: :none,
      stop_bits: 1,
      flow_control: :none,
      active: true,
      framing: {Framing, @packets},
      rx_framing_timeout: 50,
      # odometry is stamped when its frame came off the line, not when the
      # BEAM got round to it: its velocities are counts over those stamps
      rx_timestamps: true
    ]

    with :ok <- UART.open(state.uart, state.device, opts),
         :ok <- UART.write(state.uart, start_sequence(state)) do
      {:ok,
       %{
         state
         | connected: true,
           last_frame_at: nil,
           restarted_at: now_ms(),
           odometry: Odometry.rebase(state.odometry)
       }}
    else
      {:error, reason} ->
        UART.close(state.uart)
        {:error, reason, state}
    end
  catch
    :exit, reason -> {:error, {:exit, reason}, state}
  end

  defp start_sequence(state),
    do: [Protocol.start(), Protocol.mode(state.mode), Protocol.stream(@packets)]

  defp write(_state, {:error, _}), do: :ok

  defp write(state, iodata) do
    case UART.write(state.uart, iodata) do
      :ok ->
        :ok

      {:error, reason} ->
        Logger.debug("#{inspect(state.robot)}: Create 2 write failed: #{inspect(reason)}")
        :error
    end
  catch
    :exit, _ -> :error
  end

  defp schedule_reconnect(state),
    do: Process.send_after(self(), {:tc_create2, :reconnect}, state.reconnect_ms)

  # the line lost: report it at once, then try again every reconnect_every
  defp line({:error, _reason}, %{connected: false} = state), do: {[], state}

  defp line({:error, reason}, state) do
    Logger.warning(
      "#{inspect(state.robot)}: Create 2 line #{state.device} lost: #{inspect(reason)}"
    )

    state = %{state | connected: false, odometry: Odometry.rebase(state.odometry)}
    schedule_reconnect(state)
    link(state, true)
  end

  # (frames lost since the last good one: the odometry's next step spans them)
  defp line({:rejected, :garbage, bytes}, state) when is_binary(bytes) do
    lost = state.lost + div(byte_size(bytes), @frame_bytes)
    {[], %{state | garbage_bytes: state.garbage_bytes + byte_size(bytes), lost: lost}}
  end

  defp line({:rejected, reason, bytes}, state) do
    Logger.debug(
      "#{inspect(state.robot)}: Create 2 frame rejected (#{reason}): #{inspect(bytes)}"
    )

    {[], %{state | rejected: state.rejected + 1, lost: state.lost + 1}}
  end

  # a frame the framing held back when the line went quiet is whole
  defp line({:partial, bytes}, state) when is_binary(bytes) do
    case Protocol.parse_frame(bytes, @packets) do
      {:ok, _} -> line(bytes, state)
      {:error, _} -> line({:rejected, :truncated, bytes}, state)
    end
  end

  defp line(frame, state) when is_binary(frame) do
    case Protocol.parse_frame(frame, @packets) do
      {:ok, packets} -> frame(packets, %{state | frames: state.frames + 1})
      {:error, reason} -> line({:rejected, reason, frame}, state)
    end
  end

  defp line(_other, state), do: {[], state}

  defp frame(packets, state) do
    now = now_ms()
    bumps = packets[7]
    stamp = state.received_at || now / 1000
    odometry = Odometry.update(state.odometry, packets[43], packets[44], stamp, 1 + state.lost)

    bumper = %{
      pressed: bumps.bump_left or bumps.bump_right,
      left: bumps.bump_left,
      right: bumps.bump_right,
      wheel_drop: bumps.wheel_drop_left or bumps.wheel_drop_right
    }

    battery = %{
      voltage: packets[22] / 1000,
      current: packets[23] / 1000,
      charge: packets[25] / 1000,
      capacity: packets[26] / 1000,
      percent: if(packets[26] > 0, do: min(100.0, 100 * packets[25] / packets[26]), else: 0.0)
    }

    bumper_changed = bumper != state.bumper

    state = %{
      state
      | odometry: odometry,
        lost: 0,
        bumper: bumper,
        battery: battery,
        wheel_drop: bumper.wheel_drop,
        oi_mode: packets[35],
        last_frame_at: now
    }

    readings = [{state.names.odometry, Odometry.reading(odometry)}]
    readings = if bumper_changed, do: readings ++ [bumper_reading(state)], else: readings
    {link, state} = link(state, false)
    {readings ++ link, state}
  end

  # the robot stopped streaming with the line up: start it again, once a second
  defp restart_stale_stream(%{connected: true} = state, now) do
    since = state.last_frame_at || state.restarted_at || now

    if now - since >= @stale_stream_ms and now - (state.restarted_at || 0) >= @stale_stream_ms do
      Logger.info("#{inspect(state.robot)}: Create 2 not streaming; starting it again")
      write(state, start_sequence(state))
      %{state | restarted_at: now}
    else
      state
    end
  end

  defp restart_stale_stream(state, _now), do: state

  defp bumper_reading(%{bumper: nil}), do: nil
  defp bumper_reading(state), do: {state.names.bumper, state.bumper}

  defp battery_reading(%{battery: nil}), do: nil
  defp battery_reading(state), do: {:battery, state.battery}

  # the link reading when connected or the OI mode changed (or always, if asked)
  defp link(state, always) do
    streaming =
      state.connected and state.last_frame_at != nil and
        now_ms() - state.last_frame_at < @stale_stream_ms

    key = {state.connected, state.oi_mode, streaming}

    if always or key != state.published_link do
      payload = %{
        connected: state.connected,
        device: state.device,
        frames: state.frames,
        rejected: state.rejected,
        garbage_bytes: state.garbage_bytes,
        odometry_jumps: state.odometry.jumps,
        mode: state.oi_mode,
        streaming: streaming
      }

      {[{:link, payload}], %{state | published_link: key}}
    else
      {[], state}
    end
  end

  defp now_ms, do: System.monotonic_time(:millisecond)
end
