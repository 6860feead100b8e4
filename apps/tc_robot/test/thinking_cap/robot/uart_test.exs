defmodule ThinkingCap.Robot.UARTTest do
  # every test makes its own pseudo-terminal pairs; the kernel keeps them apart
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.UART
  alias ThinkingCap.Robot.UART.Framing

  @wait 5000

  defp uart(id) do
    start_supervised!(Supervisor.child_spec({UART, []}, id: id))
  end

  # a master (this test process controls both ends) and its slave opened by a second UART
  defp pair(master_opts \\ [], slave_opts \\ []) do
    master = uart(:master)
    slave = uart(:slave)
    {:ok, path} = UART.open_pty(master, master_opts)
    assert :ok = UART.open(slave, path, slave_opts)
    {master, slave, path}
  end

  # active-mode bytes for path until n have come
  defp collect(path, n, acc \\ []) do
    got = IO.iodata_length(acc)

    if got >= n do
      IO.iodata_to_binary(acc)
    else
      assert_receive {:tc_uart, ^path, data} when is_binary(data), @wait
      collect(path, n, [acc, data])
    end
  end

  defp passive_collect(uart, n, acc \\ "") do
    if byte_size(acc) >= n do
      acc
    else
      assert {:ok, data} = UART.read(uart, @wait)
      assert data != "", "nothing arrived within #{@wait} ms"
      passive_collect(uart, n, acc <> data)
    end
  end

  defp stty(path) do
    {out, 0} = System.cmd("stty", ["-F", path, "-a"])
    out |> String.split(~r/[\s;]+/) |> MapSet.new()
  end

  describe "bytes pass unchanged" do
    test "every byte value, both ways" do
      {master, slave, path} = pair()
      all = for b <- 0..255, into: <<>>, do: <<b>>

      assert :ok = UART.write(master, all)
      assert collect(path, 256) == all

      assert :ok = UART.write(slave, all)
      assert collect(path, 256) == all
    end

    test "a 64 KiB write, both ways" do
      {master, slave, path} = pair([speed: 115_200], speed: 115_200)
      data = :crypto.strong_rand_bytes(65_536)

      assert :ok = UART.write(master, data, 20_000)
      assert collect(path, 65_536) == data

      assert :ok = UART.write(slave, [data, "!"], 20_000)
      assert collect(path, 65_537) == data <> "!"
    end

    test "iodata is written in order" do
      {master, _slave, path} = pair()
      assert :ok = UART.write(master, ["ab", ?c, ["d", <<0, 255>>]])
      assert collect(path, 6) == <<"abcd", 0, 255>>
    end

    test "passive mode: read/2 returns what came, {:ok, \"\"} when nothing came in time" do
      {master, slave, _path} = pair([], active: false)
      assert {:ok, ""} = UART.read(slave, 50)

      assert :ok = UART.write(master, "passive bytes")
      assert passive_collect(slave, 13) == "passive bytes"
      refute_received {:tc_uart, _, _}
    end

    test "read/2 in active mode is refused" do
      {_master, slave, _path} = pair()
      assert {:error, :einval} = UART.read(slave, 10)
    end

    test "switching to active mode delivers what was queued" do
      {master, slave, path} = pair([], active: false)
      assert :ok = UART.write(master, "queued")
      # the bytes are in the UART once a passive read would see them: read a first byte's worth
      assert {:ok, first} = UART.read(slave, @wait)
      assert :ok = UART.write(master, "more")
      assert :ok = UART.configure(slave, active: true)
      rest = collect(path, 10 - byte_size(first))
      assert first <> rest == "queuedmore"
    end

    test "the controlling process gets the messages" do
      {master, slave, path} = pair()
      me = self()

      other =
        spawn_link(fn ->
          receive do
            {:tc_uart, ^path, data} -> send(me, {:other_got, data})
          end
        end)

      assert :ok = UART.controlling_process(slave, other)
      assert :ok = UART.write(master, "x")
      assert_receive {:other_got, "x"}, @wait
    end

    test "drain and flush on an open line" do
      {master, slave, path} = pair()
      assert :ok = UART.write(slave, "drained")
      assert :ok = UART.drain(slave)
      assert collect(path, 7) == "drained"

      for direction <- [:receive, :transmit, :both],
          do: assert(:ok = UART.flush(master, direction))

      assert :ok = UART.flush(slave)
    end

    test "a write the line cannot take in time times out" do
      master = uart(:master)
      {:ok, path} = UART.open_pty(master)
      # the slave open and never read: the pty's buffer fills
      {:ok, holder} = :file.open(String.to_charlist(path), [:read, :write, :raw, :binary])

      assert {:error, {:etimedout, message}} =
               UART.write(master, :binary.copy(<<0>>, 4 * 1024 * 1024), 200)

      assert message =~ "timed out after 200 ms"
      # the UART still works
      assert :ok = UART.write(master, "", 200)
      :file.close(holder)
    end
  end

  describe "line framing" do
    test "lines split across writes and several lines in one write" do
      {master, _slave, path} = pair([], framing: Framing.Line)
      assert :ok = UART.write(master, "hel")
      assert :ok = UART.write(master, "lo\nwor")
      assert :ok = UART.write(master, "ld\nthree\nfour\n")

      for line <- ["hello", "world", "three", "four"],
          do: assert_receive({:tc_uart, ^path, ^line}, @wait)
    end

    test "writes get the separator" do
      {master, _slave, path} =
        pair([framing: {Framing.Line, separator: "\r\n"}],
          framing: {Framing.Line, separator: "\r\n"}
        )

      assert :ok = UART.write(master, "AT")
      assert_receive {:tc_uart, ^path, "AT"}, @wait
    end

    test "a line over max_length is delivered as {:partial, data} and dropped" do
      {master, _slave, path} = pair([], framing: {Framing.Line, max_length: 8})
      assert :ok = UART.write(master, "0123456789abcdef\nok\n")
      assert_receive {:tc_uart, ^path, {:partial, long}}, @wait
      assert String.starts_with?(long, "01234567")
      assert_receive {:tc_uart, ^path, "ok"}, @wait
    end

    test "an unfinished frame is flushed by rx_framing_timeout as {:partial, data}" do
      {master, _slave, path} = pair([], framing: Framing.Line, rx_framing_timeout: 30)
      assert :ok = UART.write(master, "no end")
      assert_receive {:tc_uart, ^path, {:partial, "no end"}}, @wait
      assert :ok = UART.write(master, "next\n")
      assert_receive {:tc_uart, ^path, "next"}, @wait
    end

    test "rx_timestamps: a frame carries the moment its bytes were read, not delivered" do
      {master, slave, path} = pair([], framing: Framing.Line, rx_timestamps: true)
      # the slave's process is held; its port program still reads the line
      :sys.suspend(slave)
      written = System.monotonic_time()
      assert :ok = UART.write(master, "one\ntwo\n")
      Process.sleep(200)
      resumed = System.monotonic_time()
      :sys.resume(slave)

      assert_receive {:tc_uart, ^path, "one", at}, @wait
      assert_receive {:tc_uart, ^path, "two", ^at}, @wait
      assert at >= written
      assert System.convert_time_unit(resumed - at, :native, :millisecond) >= 150

      # without the option the same line's frames come unstamped
      assert :ok = UART.configure(slave, rx_timestamps: false)
      assert :ok = UART.write(master, "three\n")
      assert_receive {:tc_uart, ^path, "three"}, @wait
    end

    test "passive mode reads one frame at a time, partials included" do
      {master, slave, _path} =
        pair([], active: false, framing: Framing.Line, rx_framing_timeout: 30)

      assert :ok = UART.write(master, "one\ntwo\nthr")
      assert {:ok, "one"} = UART.read(slave, @wait)
      assert {:ok, "two"} = UART.read(slave, @wait)
      assert {:ok, {:partial, "thr"}} = UART.read(slave, @wait)
    end

    test "Line.remove_framing: chunks, several lines, a split separator, max_length" do
      {:ok, s} = Framing.Line.init(separator: "\r\n", max_length: 5)
      assert {:in_frame, [], s} = Framing.Line.remove_framing("ab", s)
      assert {:in_frame, [], s} = Framing.Line.remove_framing("c\r", s)
      assert {:ok, ["abc"], s} = Framing.Line.remove_framing("\n", s)
      assert {:in_frame, ["x", "y"], s} = Framing.Line.remove_framing("x\r\ny\r\nz", s)
      assert {:ok, [{:partial, "z123456"}], s} = Framing.Line.remove_framing("123456\r\n", s)
      assert {:ok, [{:partial, "toolong"}], s} = Framing.Line.remove_framing("toolong", s)
      assert {:in_frame, [], s} = Framing.Line.remove_framing("ok", s)
      assert {:ok, ["ok"], s} = Framing.Line.frame_timeout(s)
      assert {:ok, [], _} = Framing.Line.frame_timeout(s)
      assert {:ok, ["a", "\r\n"], _} = Framing.Line.add_framing("a", s)
      assert %{buffer: ""} = Framing.Line.flush(:receive, %{s | buffer: "x"})
      assert %{buffer: "x"} = Framing.Line.flush(:transmit, %{s | buffer: "x"})
      assert {:error, {:bad_option, :separator, ""}} = Framing.Line.init(separator: "")
    end
  end

  describe "termios" do
    @speeds [1200, 2400, 4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600]

    test "every speed is applied" do
      {_master, slave, path} = pair()

      for speed <- @speeds do
        assert :ok = UART.configure(slave, speed: speed)
        assert {:ok, %{speed: ^speed}} = UART.settings(slave)
        assert "#{speed}" in stty(path)
      end
    end

    test "data bits, parity, stop bits and flow control are applied" do
      {_master, slave, path} = pair()

      # a pty has no wire: the Linux pty driver forces CS8 without parity, so
      # on a pty data bits and parity are accepted and CS8, no parity kept
      for bits <- 5..8 do
        assert :ok = UART.configure(slave, data_bits: bits)
        assert {:ok, %{data_bits: 8}} = UART.settings(slave)
        assert "cs8" in stty(path)
      end

      for {parity, words} <- [
            none: ["-parenb", "-parodd"],
            even: ["-parenb", "-parodd"],
            odd: ["-parenb", "-parodd"]
          ] do
        assert :ok = UART.configure(slave, parity: parity)
        assert {:ok, %{parity: :none}} = UART.settings(slave)
        assert MapSet.subset?(MapSet.new(words), stty(path)), "#{parity}: #{inspect(words)}"
      end

      for {stop, word} <- [{2, "cstopb"}, {1, "-cstopb"}] do
        assert :ok = UART.configure(slave, stop_bits: stop)
        assert {:ok, %{stop_bits: ^stop}} = UART.settings(slave)
        assert word in stty(path)
      end

      for {flow, words} <- [
            hardware: ["crtscts", "-ixon", "-ixoff"],
            software: ["-crtscts", "ixon", "ixoff"],
            none: ["-crtscts", "-ixon", "-ixoff"]
          ] do
        assert :ok = UART.configure(slave, flow_control: flow)
        assert {:ok, %{flow_control: ^flow}} = UART.settings(slave)
        assert MapSet.subset?(MapSet.new(words), stty(path)), "#{flow}: #{inspect(words)}"
      end
    end

    test "open/3 applies its options, raw and non-canonical" do
      {_master, slave, path} =
        pair([],
          speed: 57_600,
          data_bits: 7,
          parity: :odd,
          stop_bits: 2,
          flow_control: :hardware
        )

      assert {:ok, %{speed: 57_600, stop_bits: 2, flow_control: :hardware}} = UART.settings(slave)

      words = stty(path)

      for word <- ~w(57600 cs8 -parenb cstopb crtscts clocal cread -icanon -echo -isig
                     -opost -icrnl -ixon min = 0 time) do
        assert word in words, word
      end
    end

    test "open_pty/2 puts the slave side in raw mode with its settings" do
      master = uart(:master)
      assert {:ok, path} = UART.open_pty(master, speed: 19_200, stop_bits: 2)
      words = stty(path)
      for word <- ~w(19200 cstopb cs8 -icanon -echo -opost), do: assert(word in words, word)
      assert {:ok, %{speed: 19_200, stop_bits: 2}} = UART.settings(master)
      assert :ok = UART.configure(master, speed: 4800)
      assert "4800" in stty(path)
    end
  end

  describe "errors" do
    test "bad options are {:error, {:bad_option, key, value}} and change nothing" do
      {_master, slave, _path} = pair([], speed: 38_400)
      other = uart(:other)

      for {key, value} <- [
            speed: 12_345,
            speed: "fast",
            data_bits: 9,
            parity: :mark,
            stop_bits: 3,
            flow_control: :rts,
            active: :yes,
            framing: String,
            framing: NoSuchModule,
            rx_framing_timeout: -1,
            rx_timestamps: :yes,
            bogus: 1
          ] do
        assert {:error, {:bad_option, ^key, ^value}} = UART.configure(slave, [{key, value}])

        assert {:error, {:bad_option, ^key, ^value}} =
                 UART.open(other, "/dev/null", [{key, value}])

        assert {:error, {:bad_option, ^key, ^value}} = UART.open_pty(other, [{key, value}])
      end

      assert {:error, {:bad_option, :separator, ""}} =
               UART.configure(slave, framing: {Framing.Line, separator: ""})

      assert {:error, {:bad_option, :path, :nope}} = UART.open(other, :nope)
      assert {:ok, %{speed: 38_400}} = UART.settings(slave)
    end

    test "a missing device, a file that is no tty" do
      u = uart(:u)

      assert {:error, {:enoent, "open /dev/ttyNOPE0: No such file or directory"}} =
               UART.open(u, "/dev/ttyNOPE0")

      assert {:error, {:enotty, message}} = UART.open(u, "/dev/null")
      assert message =~ "/dev/null"
    end

    test "a closed or never opened UART: write and read are {:error, :ebadf}" do
      u = uart(:u)
      assert {:error, :ebadf} = UART.write(u, "x")
      assert {:error, :ebadf} = UART.read(u, 10)
      assert {:error, :ebadf} = UART.drain(u)
      assert {:error, :ebadf} = UART.configure(u, speed: 9600)
      assert :ok = UART.close(u)

      {_master, slave, _path} = pair()
      assert :ok = UART.close(slave)
      assert {:error, :ebadf} = UART.write(slave, "x")
      assert {:error, :ebadf} = UART.read(slave, 10)
    end

    test "an open UART refuses another open" do
      {master, slave, path} = pair()
      assert {:error, :ealready} = UART.open(slave, path)
      assert {:error, :ealready} = UART.open_pty(master)
    end

    test "bad frames get an error reply and the port program carries on" do
      exe = Application.app_dir(:tc_robot, "priv/bin/tc_uart")
      port = Port.open({:spawn_executable, exe}, [:binary, {:packet, 4}, :exit_status])
      assert_receive {^port, {:data, <<?H, _::binary>>}}, @wait

      for frame <- [<<>>, "Z", "O", <<?O, 0::32>>, "P1", "Cxx", <<?F, 9>>, "W", "Wabcdefg", "D"] do
        Port.command(port, frame)
        assert_receive {^port, {:data, <<?E, n, _code::binary-size(n), text::binary>>}}, @wait
        assert text != ""
      end

      Port.command(port, <<?P, 9600::32, 8, 0, 1, 0>>)
      assert_receive {^port, {:data, <<?K, "/dev/pts/", _::binary>>}}, @wait
      Port.close(port)
    end
  end

  describe "the line going away" do
    test "the master closed: the slave's UART hears it and can open a new pty" do
      {master, slave, path} = pair()
      assert :ok = UART.close(master)
      assert_receive {:tc_uart, ^path, {:error, reason}}, @wait
      assert reason in [:eio, :closed]
      assert {:error, :ebadf} = UART.write(slave, "x")

      assert {:ok, path2} = UART.open_pty(master)
      assert :ok = UART.open(slave, path2)
      assert :ok = UART.write(slave, "again")
      assert collect(path2, 5) == "again"
    end

    test "in passive mode the error is read" do
      {master, slave, _path} = pair([], active: false)
      assert :ok = UART.close(master)
      assert {:error, reason} = UART.read(slave, @wait)
      assert reason in [:eio, :closed]
      assert {:error, :ebadf} = UART.read(slave, 10)
    end

    test "the slave closing and reopening leaves the master open" do
      {master, slave, path} = pair()
      assert :ok = UART.close(slave)
      assert :ok = UART.open(slave, path)
      assert :ok = UART.write(slave, "still there")
      assert collect(path, 11) == "still there"
      assert :ok = UART.write(master, "both ways")
      assert collect(path, 9) == "both ways"
      refute_received {:tc_uart, _, {:error, _}}
    end

    test "the port program killed: {:error, :port_died}, and the UART works after reopening" do
      {master, slave, path} = pair()
      os_pid = UART.os_pid(slave)
      {_, 0} = System.cmd("kill", ["-9", "#{os_pid}"])
      assert_receive {:tc_uart, ^path, {:error, :port_died}}, @wait
      assert {:error, :ebadf} = UART.write(slave, "x")
      assert UART.os_pid(slave) != os_pid

      assert :ok = UART.open(slave, path)
      assert :ok = UART.write(master, "alive")
      assert collect(path, 5) == "alive"
      assert :ok = UART.write(slave, "too")
      assert collect(path, 3) == "too"
    end

    test "the master's port program killed: the master reports it, the slave's line goes away" do
      {master, _slave, path} = pair()
      {_, 0} = System.cmd("kill", ["-9", "#{UART.os_pid(master)}"])
      assert_receive {:tc_uart, ^path, {:error, :port_died}}, @wait
      assert_receive {:tc_uart, ^path, {:error, reason}} when reason in [:eio, :closed], @wait
      assert {:ok, _} = UART.open_pty(master)
    end
  end

  test "enumerate lists existing paths only" do
    ports = UART.enumerate()
    assert is_map(ports)

    for {path, info} <- ports do
      assert File.exists?(path), path
      assert is_map(info)
      assert String.starts_with?(path, "/dev/")
    end
  end
end
