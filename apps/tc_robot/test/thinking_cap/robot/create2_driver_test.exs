defmodule ThinkingCap.Robot.Create2DriverTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Robot.{Create2, Description}
  alias ThinkingCap.Robot.Create2.Protocol

  @rdf Path.expand("../../../../../priv/examples/create2.rdf", __DIR__)

  setup_all do
    {:ok, description} = Description.load(@rdf)
    %{description: description}
  end

  defp wheels(<<145, right::16-signed, left::16-signed>>), do: {left, right}

  # the driver opened on an emulated Create 2 at dir/create2, closed at exit
  defp open_on_emulator(d, dir) do
    link = Path.join(dir, "create2")
    start_supervised!({ThinkingCap.Testing.Create2Emulator, link: link})
    assert {:ok, state} = Create2.open(d, %{robot: :c, params: [device: link]})
    on_exit(fn -> Create2.close(:normal, state) end)
    {link, state}
  end

  describe "encode_command/2" do
    test "velocities through the RDF's kinematics, in mm/s a wheel", %{description: d} do
      assert Create2.encode_command({:velocity, 0.2, 0.0}, d) == Protocol.drive_direct(200, 200)
      assert wheels(Create2.encode_command({:velocity, -0.1, 0.0}, d)) == {-100, -100}
      # turning in place: omega * b / 2 = 117.5 mm/s
      assert wheels(Create2.encode_command({:velocity, 0.0, 1.0}, d)) == {-118, 118}
      # an arc to the left: the right wheel faster
      {l, r} = wheels(Create2.encode_command({:velocity, 0.2, 0.5}, d))
      assert_in_delta l, 200 - 58.75, 1
      assert_in_delta r, 200 + 58.75, 1
    end

    test "wheel speeds in rad/s times the wheel radius", %{description: d} do
      # 5 rad/s * 36 mm = 180 mm/s
      assert wheels(Create2.encode_command({:wheels, 5.0, -2.5}, d)) == {180, -90}
    end

    test "too fast: both wheels scaled down together, the curvature kept", %{description: d} do
      {l, r} = wheels(Create2.encode_command({:velocity, 0.5, 2.0}, d))
      assert r == 500
      # unscaled: 265 and 735 mm/s
      assert_in_delta l / r, 265 / 735, 0.01
      assert wheels(Create2.encode_command({:wheels, 100.0, 100.0}, d)) == {500, 500}
    end

    test ":stop is Drive Direct 0 0; other commands and drives are refused", %{description: d} do
      assert Create2.encode_command(:stop, d) == <<145, 0, 0, 0, 0>>
      assert {:error, _} = Create2.encode_command({:steer, 0.2, 0.1}, d)
      assert {:error, _} = Create2.encode_command(:fly, d)

      car = %{
        d
        | kinematics:
            ThinkingCap.Robot.Kinematics.new(type: :tricycle, wheelbase: 0.5, max_steering: 1.0)
      }

      assert {:error, :not_differential} = Create2.encode_command(:stop, car)
    end
  end

  describe "odometry stamps" do
    @tag :tmp_dir
    test "are when the frame came off the line, not when the driver got it", %{
      description: d,
      tmp_dir: dir
    } do
      {link, state} = open_on_emulator(d, dir)

      # the driver's UART reports to this process: a frame handed to the
      # driver 200 ms after it was read keeps the moment it was read
      assert_receive {:tc_uart, _path, frame, read_at} when is_binary(frame), 5_000
      Process.sleep(200)
      handled = System.monotonic_time()

      assert {[{:odometry, odometry} | _], _state} =
               Create2.handle_data({:tc_uart, link, frame, read_at}, state)

      assert odometry.stamp == System.convert_time_unit(read_at, :native, :microsecond) / 1.0e6
      assert System.convert_time_unit(handled - read_at, :native, :millisecond) >= 200
    end

    @tag :tmp_dir
    test "a step over frames rejected in the same read is driven, not a jump", %{
      description: d,
      tmp_dir: dir
    } do
      {link, state} = open_on_emulator(d, dir)

      frame = fn counts ->
        Protocol.stream_frame(
          for id <- Create2.packets() do
            value =
              case id do
                7 ->
                  %{
                    bump_left: false,
                    bump_right: false,
                    wheel_drop_left: false,
                    wheel_drop_right: false
                  }

                35 ->
                  :safe

                id when id in [43, 44] ->
                  counts

                26 ->
                  2000

                _ ->
                  0
              end

            {id, value}
          end
        )
      end

      # the stream running: the emulator's own frame first
      assert_receive {:tc_uart, _path, first, first_at} when is_binary(first), 5_000
      {_actions, state} = Create2.handle_data({:tc_uart, link, first, first_at}, state)

      # what the UART's framing cut from one read of the line, all with
      # that read's stamp: a good frame, ten with a bad checksum (the
      # wheels moved 127 counts meanwhile, 56 mm), and the next good one
      read_at = System.monotonic_time()
      rejected = List.duplicate({:rejected, :checksum, frame.(1050)}, 10)

      {poses, _state} =
        Enum.flat_map_reduce([frame.(1000)] ++ rejected ++ [frame.(1127)], state, fn data, st ->
          {actions, st} = Create2.handle_data({:tc_uart, link, data, read_at}, st)
          {for({:odometry, o} <- actions, do: o.pose), st}
        end)

      [{x0, _, _}, {x1, _, _}] = poses
      assert_in_delta x1 - x0, 127 * 2 * :math.pi() * 0.036 / 508.8, 0.002
    end
  end

  describe "open/2" do
    test "refuses a missing device, a bad mode, a device that is not there", %{description: d} do
      context = fn params -> %{robot: :c, params: params} end
      assert {:error, "device:" <> _} = Create2.open(d, context.([]))
      assert {:error, "mode:" <> _} = Create2.open(d, context.(device: "/dev/null", mode: :turbo))

      assert {:error, {:open, "/nonexistent/tty", _}} =
               Create2.open(d, context.(device: "/nonexistent/tty"))
    end
  end

  test "the example ADF selects the driver on a device, over the example RDF" do
    adf = Path.join(Path.dirname(@rdf), "create2.adf")
    assert {:ok, %ThinkingCap.Config.ADF{rdf: @rdf} = config} = ThinkingCap.Config.read(adf)
    assert [{:base, base}] = Enum.map(config.modules, &{&1.name, &1})
    assert base.module == Create2
    assert base.params[:device] == "/dev/ttyUSB0"
  end

  test "the streamed packets are known and fit a frame" do
    assert is_integer(Protocol.stream_length(Create2.packets()))
  end
end
