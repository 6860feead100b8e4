defmodule ThinkingCap.BlackBox.BumperDumpTest do
  # Hosts a robot in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.MCAP.Reader
  alias ThinkingCap.Testing.Sim, as: T
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :tmp_dir
  @moduletag timeout: 60_000

  test "a bumper contact in a test world produces a dump without anyone asking", %{tmp_dir: dir} do
    robot = :"bump#{System.unique_integer([:positive])}"
    dumps = Path.join(dir, "black_box")
    # a small box; the robot starts 0.6 m from its east wall, facing it
    wdf = T.wdf!(dir, walls: T.box(2, 2), waypoints: [[name: :start, at: {1.2, 1, 0}]])
    laser = [name: :laser, type: :laser, range: {0.05, 4.0}, fov: 3.14, beams: 31, rate: 10]
    rdf = T.rdf!(dir, sensors: [laser, [name: :bumper, type: :bumper, rate: 20]])
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: #{inspect(rdf)},
      wdf: #{inspect(wdf)},
      black_box: [enabled: true, dir: #{inspect(dumps)}, seconds: 30, after: 0.3],
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                        deadline: 0.005, fallback: :stop, params: [at: :start]]
      ]
    ]
    """)

    adf = Config.read!(path)
    {:ok, _ref} = Blackboard.subscribe(Tuples.black_box_dump(robot))

    on_exit(fn ->
      for m <- adf.modules, do: Runtime.stop(m.name)
      ThinkingCap.BlackBox.forget(robot)
    end)

    {:ok, _} = Runtime.start(adf)
    # the announcement starts the black box
    assert {:ok, _} = Blackboard.rd(Tuples.reading(:laser, robot), 5_000)
    assert wait_until(fn -> ThinkingCap.BlackBox.ring_buffer(robot) end)

    # drive ahead, into the wall, as a controller would
    driver =
      spawn_link(fn ->
        Stream.repeatedly(fn ->
          Blackboard.out(Tuples.drive(robot, %{command: {:velocity, 0.5, 0.0}}))
          Process.sleep(50)
        end)
        |> Stream.run()
      end)

    assert_receive {:blackboard, _, Tuples.black_box_dump(^robot, dump)}, 20_000
    Process.unlink(driver)
    Process.exit(driver, :kill)

    assert dump.reason == "bumper"
    assert Path.dirname(dump.path) == dumps
    assert [%{path: listed}] = ThinkingCap.BlackBox.dumps(robot)
    assert listed == dump.path

    assert {:ok, mcap} = Reader.read(dump.path)
    assert mcap.mode == :indexed and mcap.data_crc == :valid
    topic = Map.new(mcap.channels, fn {id, c} -> {id, c.topic} end)
    on = fn name -> Enum.filter(mcap.messages, &(topic[&1.channel_id] == "/#{robot}/#{name}")) end

    contact =
      Enum.find(on.("bumper"), fn m ->
        :jiffy.decode(m.data, [:return_maps])["payload"]["pressed"] == true
      end)

    assert contact, "no pressed bumper in the dump"
    # what the robot sensed and did on its way to the wall
    before = fn name -> Enum.count(on.(name), &(&1.log_time < contact.log_time)) end
    assert before.("laser") > 3
    assert before.("sim_pose") > 3
    assert before.("drive") > 3
    assert hd(on.("laser")).log_time < contact.log_time
  end

  defp wait_until(fun, timeout \\ 5_000) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      Process.sleep(20)
      fun.()
    end)
    |> Enum.find(fn result -> result || System.monotonic_time(:millisecond) > deadline end)
  end
end
