defmodule ThinkingCap.Robot.Create2EmulatorTest do
  # ptys and timers: not beside other tests
  use ExUnit.Case, async: false

  import ThinkingCap.Robot.Test.Eventually

  alias ThinkingCap.Robot.UART
  alias ThinkingCap.Robot.Create2.{Framing, Protocol}
  alias ThinkingCap.Testing.Create2Emulator, as: Emulator

  @moduletag :tmp_dir
  @ids [7, 19, 20, 35, 43, 44]

  setup %{tmp_dir: dir} do
    link = Path.join(dir, "create2")
    emu = start_supervised!({Emulator, link: link})
    {:ok, uart} = UART.start_link([])
    on_exit(fn -> if Process.alive?(uart), do: UART.stop(uart) end)
    %{emu: emu, link: link, uart: uart}
  end

  defp open(uart, link, framing \\ nil) do
    opts = [speed: 115_200, active: true]
    opts = if framing, do: Keyword.put(opts, :framing, framing), else: opts
    assert :ok = UART.open(uart, link, opts)
  end

  # the next valid stream frame's packets
  defp next_frame(link) do
    receive do
      {:tc_uart, ^link, frame} when is_binary(frame) ->
        {:ok, packets} = Protocol.parse_frame(frame, @ids)
        packets

      {:tc_uart, ^link, _other} ->
        next_frame(link)
    after
      2000 -> flunk("no stream frame")
    end
  end

  test "the link points at the pty; Off until Start; drive commands only in Safe or Full", %{
    emu: emu,
    link: link,
    uart: uart
  } do
    assert {:ok, "/dev/pts/" <> _} = File.read_link(link)
    open(uart, link)
    assert %{mode: :off, left: 0, right: 0, plugged?: true} = Emulator.state(emu)

    # ignored when Off and when Passive
    :ok = UART.write(uart, Protocol.drive_direct(100, 100))
    :ok = UART.write(uart, Protocol.start())
    eventually(fn -> assert %{mode: :passive} = Emulator.state(emu) end)
    :ok = UART.write(uart, Protocol.drive_direct(100, 100))
    eventually(fn -> assert [%{applied: false}] = Emulator.commands(emu) end)
    assert %{left: 0, right: 0} = Emulator.state(emu)

    # a command split across writes
    :ok = UART.write(uart, [Protocol.safe(), 145, 0])
    Process.sleep(30)
    :ok = UART.write(uart, <<200, 0xFF, 0x38>>)

    eventually(fn ->
      assert %{mode: :safe, left: -200, right: 200} = Emulator.state(emu)
    end)

    assert [_, %{command: {:drive_direct, -200, 200}, applied: true, at: at}] =
             Emulator.commands(emu)

    assert is_integer(at)

    # turning in place: the heading grows, the position stays
    Process.sleep(300)
    %{pose: {x, y, theta}} = Emulator.state(emu)
    assert theta > 0.3
    assert_in_delta x, 0.0, 0.001
    assert_in_delta y, 0.0, 0.001

    # Drive with a special radius: straight
    :ok = UART.write(uart, [Protocol.full(), Protocol.drive(150, :straight)])
    eventually(fn -> assert %{mode: :full, left: 150, right: 150} = Emulator.state(emu) end)

    :ok = UART.write(uart, Protocol.stop())
    eventually(fn -> assert %{mode: :off, left: 0, right: 0} = Emulator.state(emu) end)
  end

  test "sensors, query list, stream with checksums; encoder counts follow the wheels", %{
    emu: emu,
    link: link,
    uart: uart
  } do
    open(uart, link)
    :ok = UART.write(uart, [Protocol.start(), Protocol.safe(), Protocol.sensors(35)])
    assert_receive {:tc_uart, ^link, <<2>>}, 2000

    :ok = UART.write(uart, Protocol.query_list([35, 43, 44]))
    assert_receive {:tc_uart, ^link, <<2, 0, 0, 0, 0>>}, 2000

    UART.close(uart)
    open(uart, link, {Framing, @ids})
    :ok = UART.write(uart, [Protocol.stream(@ids), Protocol.drive_direct(200, 200)])

    p = next_frame(link)
    assert p[35] == :safe
    assert %{bump_left: false} = p[7]

    Process.sleep(500)
    :ok = UART.write(uart, Protocol.drive_direct(0, 0))
    eventually(fn -> assert %{left: 0, right: 0} = Emulator.state(emu) end)
    Process.sleep(50)
    flush_frames(link)
    p = next_frame(link)
    %{pose: {x, _, _}, left_counts: l} = Emulator.state(emu)
    # about 100 mm in 0.5 s, at rest now: 508.8 / (72 pi) counts a mm
    assert x > 0.08
    assert_in_delta p[43], l, 1
    assert_in_delta p[44], l, 1

    # bumps, and the stream paused and resumed
    Emulator.bump(emu, :left)
    eventually(fn -> assert %{bump_left: true, bump_right: false} = next_frame(link)[7] end)
    :ok = UART.write(uart, Protocol.pause_stream())
    eventually(fn -> assert %{streaming?: false} = Emulator.state(emu) end)
    Process.sleep(50)
    flush_frames(link)
    refute_receive {:tc_uart, ^link, _}, 100
    :ok = UART.write(uart, Protocol.resume_stream())
    assert next_frame(link)[35] == :safe
  end

  test "faults: corrupted and truncated frames, garbage, a wheel drop in Safe mode", %{
    emu: emu,
    link: link,
    uart: uart
  } do
    open(uart, link, {Framing, @ids})
    :ok = UART.write(uart, [Protocol.start(), Protocol.safe(), Protocol.stream(@ids)])
    next_frame(link)

    Emulator.corrupt(emu, 2)
    assert_receive {:tc_uart, ^link, {:rejected, :checksum, _}}, 2000
    assert_receive {:tc_uart, ^link, {:rejected, :checksum, _}}, 2000

    Emulator.truncate(emu, 1)
    assert_receive {:tc_uart, ^link, {:rejected, :truncated, _}}, 2000
    next_frame(link)

    Emulator.garbage(emu, <<1, 2, 3, 4>>)
    assert_receive {:tc_uart, ^link, {:rejected, :garbage, <<1, 2, 3, 4>>}}, 2000
    next_frame(link)

    :ok = UART.write(uart, Protocol.drive_direct(100, 100))
    eventually(fn -> assert %{left: 100} = Emulator.state(emu) end)
    Emulator.wheel_drop(emu, true)
    assert %{mode: :passive, left: 0, right: 0} = Emulator.state(emu)
    eventually(fn -> assert %{wheel_drop_left: true} = next_frame(link)[7] end)
  end

  test "unplug closes the line and removes the link; replug re-points it", %{
    emu: emu,
    link: link,
    uart: uart
  } do
    open(uart, link, {Framing, @ids})
    :ok = UART.write(uart, [Protocol.start(), Protocol.stream(@ids)])
    next_frame(link)

    :ok = Emulator.unplug(emu)
    assert_receive {:tc_uart, ^link, {:error, _}}, 2000
    refute File.exists?(link)
    assert {:error, _} = UART.open(uart, link, speed: 115_200)

    :ok = Emulator.replug(emu)
    assert {:ok, "/dev/pts/" <> _} = File.read_link(link)
    open(uart, link, {Framing, @ids})
    # the robot kept its mode and stream across the cable
    assert next_frame(link)[35] == :passive
  end

  # a later test's pty may get the same /dev/pts/N: a link left behind
  # would lead whatever still opens it (a driver, a wire) to that pty
  test "stopped by its supervisor, the emulator takes its link away", %{emu: emu} do
    link = Emulator.link(emu)
    assert {:ok, "/dev/pts/" <> _} = File.read_link(link)
    :ok = stop_supervised(Emulator)
    assert {:error, :enoent} = File.read_link(link)
  end

  defp flush_frames(link) do
    receive do
      {:tc_uart, ^link, _} -> flush_frames(link)
    after
      0 -> :ok
    end
  end
end
