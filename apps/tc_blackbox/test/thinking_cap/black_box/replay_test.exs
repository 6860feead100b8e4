defmodule ThinkingCap.BlackBox.ReplayTest do
  # The example robot (priv/examples/office_sim.adf: the simulated office
  # robot and its whole stack) recorded in this node's runtime for a few
  # seconds, then its modules replayed: not beside other tests.
  use ExUnit.Case, async: false

  import ExUnit.CaptureIO

  alias ThinkingCap.BlackBox.Replay, as: BlackBoxReplay
  alias ThinkingCap.Blackboard
  alias ThinkingCap.Testing.Replay
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag timeout: 120_000

  @adf Path.expand("../../../../../priv/examples/office_sim.adf", __DIR__)

  setup_all do
    dir = Path.join(System.tmp_dir!(), "tc_replay_test_#{System.unique_integer([:positive])}")
    robot = :"replay#{System.unique_integer([:positive])}"
    on_exit(fn -> File.rm_rf!(dir) end)
    {:ok, files} = Replay.record(@adf, seconds: 4, dir: dir, robot: robot)

    # nothing of the robot left running: not in the simulation, its
    # tuples off the blackboard
    for {_wdf, sim} <- ThinkingCap.Sim.Worlds.all(),
        do: refute(Map.has_key?(ThinkingCap.Sim.robots(sim), robot))

    Process.sleep(100)
    assert Blackboard.rd_all({:_, robot, :_}) == []
    %{files: files, robot: robot}
  end

  # what a replay fed leaves the blackboard with the test
  defp drain(robot) do
    if Blackboard.takep({:_, robot, :_}) != :none, do: drain(robot)
  end

  test "the controller replays to identical outputs", %{files: files} do
    report = files |> Replay.run(:control) |> Replay.assert_identical()
    assert report.module == ThinkingCap.Control.Blender
    # its init (subscriptions, its limits as params), then 10 Hz cycles,
    # each with its command and two tuples (drive, activation)
    cycles = div(report.outputs - 5, 3)
    assert cycles >= 20
    assert report.stopped == nil and report.differences == 0
  end

  test "the localizer replays to identical outputs", %{files: files} do
    report = files |> Replay.run(:localization) |> Replay.assert_identical()
    assert report.module == ThinkingCap.Navigation.MCL
    # odometry and laser readings, and the poses it published from them
    assert report.callbacks > 100
    assert report.outputs > 20
  end

  test "the planner replays to identical outputs, its durations aside", %{files: files} do
    report = files |> Replay.run(:planner) |> Replay.assert_identical()
    assert report.module == ThinkingCap.Planner.Monitor
    assert report.callbacks > 10
    # the plans it published, equal but for its searches' durations
    # (measured again, and so not the same)
    assert report.outputs > 10
    assert report.measured > 0
  end

  test "a module changed parts from what was recorded, and the report says where",
       %{files: files} do
    report = Replay.run(files, :control, params: [max_speed: 0.05])
    refute report.identical
    assert report.differences > 0
    assert report.equal < report.outputs

    # the first: its init sets the limit it drives within as a param
    [first | _] = report.first_differences
    assert first.callback == 0
    assert {:set_param, :max_speed, 0.05} in List.wrap(first.replayed)

    # and its commands: never faster than the new limit
    drives =
      for %{replayed: {:out, Tuples.drive(_, %{command: {:velocity, v, _}}), _}} <-
            report.first_differences,
          do: v

    assert Enum.all?(drives, &(&1 <= 0.05))

    error = assert_raise ExUnit.AssertionError, fn -> Replay.assert_identical(report) end
    assert error.message =~ ":control (ThinkingCap.Control.Blender) did not replay identically"
    assert error.message =~ "callback 0"
  end

  test "a replay feeds the blackboard and writes what the modules run again write",
       %{files: files, robot: robot} do
    on_exit(fn -> drain(robot) end)
    {:ok, rec} = BlackBoxReplay.open(files)
    assert BlackBoxReplay.robot(rec) == robot

    names = rec |> BlackBoxReplay.modules() |> Enum.map(& &1.name)
    # the robot's driver is not traced: its outputs are what the robot sensed
    assert names == [:control, :localization, :mapper, :perception, :planner]

    {:ok, _} = Blackboard.subscribe(Tuples.drive(robot))
    {:ok, _} = Blackboard.subscribe(Tuples.reading(:laser, robot))
    {:ok, _} = Blackboard.subscribe(Tuples.plan(robot))

    assert {:ok, result} = BlackBoxReplay.run(rec, speed: :max, only: [:control])
    assert result.modules.control.identical
    assert result.fed > 100 and result.left_out > 20

    # the drive commands the controller wrote again (one a cycle), the
    # readings and the plans fed as recorded
    {:ok, %{control: compared}} = BlackBoxReplay.compare(rec, :control)
    received = Enum.group_by(delivered(), &elem(&1, 0))
    assert length(received[:drive]) == div(compared.outputs - 5, 3)
    assert length(received[:laser]) > 20
    assert length(received[:plan]) > 5
  end

  defp delivered(acc \\ []) do
    receive do
      {:blackboard, _ref, tuple} -> delivered([tuple | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  test "a replay keeps its own clock: scaled real time, or steps", %{files: files, robot: robot} do
    on_exit(fn -> drain(robot) end)
    {:ok, rec} = BlackBoxReplay.open(files)

    # eight times real time: never sooner than the recording's span allows
    span = BlackBoxReplay.duration(rec)
    started = System.monotonic_time(:millisecond)
    assert {:ok, _} = BlackBoxReplay.run(rec, speed: 8.0, only: [:planner])
    assert System.monotonic_time(:millisecond) - started >= span / 8 * 1000 - 50

    # stepped: each tuple and each callback waits for the step function
    me = self()

    step = fn item ->
      send(me, {:step, item})
      n = Process.get(:steps, 0) + 1
      Process.put(:steps, n)

      cond do
        n == 3 -> {:skip, 5}
        n < 6 -> :continue
        true -> :stop
      end
    end

    assert {:ok, result} = BlackBoxReplay.run(rec, step: step, only: [:planner])
    # 2 asked, 1 asked then 5 not, 3 more asked, the last stopped
    assert length(for _ <- 1..6, do: assert_receive({:step, %{time: _, text: _}})) == 6
    refute_received {:step, _}
    assert result.fed + result.modules.planner.callbacks == 10
  end

  test "options and names are checked before anything runs", %{files: files} do
    {:ok, rec} = BlackBoxReplay.open(files)

    assert {:error, message} = BlackBoxReplay.run(rec, sped: 2)
    assert message =~ "unknown option :sped"
    assert {:error, message} = BlackBoxReplay.run(rec, speed: -1)
    assert message =~ "speed: expected a positive number or :max"
    assert {:error, message} = BlackBoxReplay.run(rec, only: [:nosuch])

    assert message =~
             "no trace of :nosuch in the recording " <>
               "(traced: :control, :localization, :mapper, :perception, :planner)"

    assert {:error, message} = BlackBoxReplay.compare(rec, :base)
    assert message =~ "no trace of :base"

    assert_raise ArgumentError, ~r/replay of :base: no trace of :base/, fn ->
      Replay.run(files, :base)
    end
  end

  test "mix tc.replay replays a recording and sums it up", %{files: files, robot: robot} do
    on_exit(fn -> drain(robot) end)

    output =
      capture_io(fn ->
        Mix.Tasks.Tc.Replay.run(files ++ ~w(--speed max --only control,planner))
      end)

    assert output =~ "robot #{robot}"
    assert output =~ "control: ThinkingCap.Control.Blender, periodic"
    assert output =~ ~r/control: \d+ callbacks, (\d+) of \1 outputs equal/
    assert output =~ ~r/planner: \d+ callbacks, (\d+) of \1 outputs equal/
    refute output =~ ~r/^localization: \d+ callbacks/m
    assert output =~ ~r/replay: fed=\d+ left_out=\d+ outputs=\d+ equal=\d+ replay_equal_pct=100.0/

    # stepped: Enter for one, a number for that many, q to stop
    output =
      capture_io("\n3\nq\n", fn ->
        Mix.Tasks.Tc.Replay.run(files ++ ~w(--step --only planner))
      end)

    assert [_, _, _] = Regex.scan(~r/t=\d+\.\d{3} s (fed|planner callback) .*? > /, output)
    assert output =~ ~r/planner: \d+ callbacks/
    assert output =~ ~r/replay: fed=\d+ /

    [_, fed] = Regex.run(~r/replay: fed=(\d+)/, output)
    [_, callbacks] = Regex.run(~r/planner: (\d+) callbacks/, output)
    # one, then three: four in all before the q
    assert String.to_integer(fed) + String.to_integer(callbacks) == 4

    assert_raise Mix.Error, ~r/give --speed or --step, not both/, fn ->
      Mix.Tasks.Tc.Replay.run(files ++ ~w(--step --speed 2))
    end

    assert_raise Mix.Error, ~r/--only: no module nosuch in the recording/, fn ->
      capture_io(fn -> Mix.Tasks.Tc.Replay.run(files ++ ~w(--only nosuch)) end)
    end

    assert_raise Mix.Error, ~r/--speed: expected a positive number or max/, fn ->
      Mix.Tasks.Tc.Replay.run(files ++ ~w(--speed fast))
    end

    assert_raise Mix.Error, ~r/no recording given/, fn -> Mix.Tasks.Tc.Replay.run([]) end
  end
end
