defmodule ThinkingCap.Testing.Replay do
  @moduledoc """
  Replays recorded modules in a test: runs a module again on exactly
  what it received in a recording and compares its outputs with the
  recorded ones (`ThinkingCap.BlackBox.Replay`, where the docs say what
  replays identically and what cannot).

      alias ThinkingCap.Testing.Replay

      @tag :tmp_dir
      test "the controller does again what it did", %{tmp_dir: dir} do
        {:ok, files} = Replay.record("priv/examples/office_sim.adf", seconds: 3, dir: dir)

        files
        |> Replay.run(:control)
        |> Replay.assert_identical()
      end

  A recording made elsewhere (`bin/run --record DIR`, a robot's ADF
  `record:` section) replays the same way: `Replay.run(path, :planner)`.
  A module's new version is checked against what the old one did by
  running it in the recorded module's place (`module:`): the report then
  shows where they part.

  Tests that record host a robot in the node's runtime: run them with
  `async: false`, and give each its own robot (`robot:`).
  """

  alias ThinkingCap.BlackBox
  alias ThinkingCap.BlackBox.Replay
  alias ThinkingCap.{Blackboard, Config, Runtime, Tuples}
  alias ThinkingCap.Config.ADF
  require Tuples

  @doc """
  Records a run of `adf` (a path or a `ThinkingCap.Config.ADF`) on this
  node for `seconds`, in real time, into `dir`; returns the recording's
  files. Its modules start after the recorder, so they are traced from
  their `init/2`; they are stopped at the end, the recording closed, and
  the robot taken out of the simulation (`ThinkingCap.Sim.Robot` leaves
  it there when it stops) and its tuples off the blackboard. Its
  dashboard and black box are not started. Options: `seconds:` and `dir:` (required),
  `robot:` (run the ADF's robot under this name).
  """
  @spec record(Path.t() | ADF.t(), keyword()) :: {:ok, [Path.t()]} | {:error, String.t()}
  def record(adf, opts) do
    with {:ok, adf} <- Config.adf(adf),
         {:ok, seconds, dir} <- record_options(opts) do
      robot = Keyword.get(opts, :robot, adf.robot)

      adf = %{
        adf
        | robot: robot,
          dashboard: Map.put(adf.dashboard, :enabled, false),
          black_box: Map.put(adf.black_box, :enabled, false),
          record: Map.merge(adf.record, %{enabled: true, dir: dir})
      }

      try do
        case Runtime.start(adf) do
          {:ok, _modules} ->
            Process.sleep(round(seconds * 1000))
            recorder = BlackBox.recorder(robot)
            files = if recorder, do: BlackBox.Recorder.info(recorder).files, else: []
            if files == [], do: {:error, "#{robot} was not recorded"}, else: {:ok, files}

          {:error, failed} ->
            {:error, "could not start #{adf.file}: #{inspect(failed)}"}
        end
      after
        stop(adf)
      end
    end
  end

  defp record_options(opts) do
    case {opts[:seconds], opts[:dir]} do
      {s, dir} when is_number(s) and s > 0 and is_binary(dir) -> {:ok, s, dir}
      _ -> {:error, "record/2 needs seconds: (a positive number) and dir: (a path)"}
    end
  end

  # modules first, so that the recording holds their last callbacks
  defp stop(adf) do
    for m <- adf.modules, do: Runtime.stop({adf.robot, m.name})
    BlackBox.stop(adf.robot)
    leave_simulations(adf.robot)
    drain({:_, adf.robot, :_})
    for %{activity: :periodic, name: name} <- adf.modules, do: drain(Tuples.timing(name))
  end

  # A simulated robot's body stays in its world when its driver stops (a
  # driver started again takes it over), sensing and publishing: the
  # recorded robot is taken out of every simulation running here. The
  # simulator is not a dependency of this app: it is found at run time.
  defp leave_simulations(robot) do
    worlds = Module.concat([ThinkingCap, Sim, Worlds])
    sim = Module.concat([ThinkingCap, Sim])

    if Code.ensure_loaded?(worlds) do
      for {_wdf, pid} <- apply(worlds, :all, []) do
        try do
          apply(sim, :remove_robot, [pid, robot])
        catch
          :exit, _gone -> :ok
        end
      end
    end

    :ok
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  @doc """
  Runs module `name` of the recording in `paths` (a file, or the files
  of one recording) again and compares its outputs: the report of
  `ThinkingCap.BlackBox.Replay.compare/3`. Options: `robot:` (among
  files of several robots), `module:` (run this module's code in its
  place) and `params:` (over the recorded params). Raises
  `ArgumentError` when the recording cannot be read or has no trace of
  `name`.
  """
  @spec run(Path.t() | [Path.t()], atom(), keyword()) :: Replay.report()
  def run(paths, name, opts \\ []) do
    {robot, opts} = Keyword.pop(opts, :robot)

    with {:ok, rec} <- Replay.open(paths, robot: robot),
         {:ok, %{^name => report}} <- Replay.compare(rec, name, opts) do
      report
    else
      {:error, message} -> raise ArgumentError, "replay of #{inspect(name)}: #{message}"
    end
  end

  @doc """
  Fails the test unless the replay was identical: every output equal
  (declared measurements aside), the recording run to its end, and at
  least one callback run. The message shows the first differences.
  """
  @spec assert_identical(Replay.report()) :: Replay.report()
  def assert_identical(%{identical: true} = report), do: report

  def assert_identical(report) do
    ExUnit.Assertions.flunk("""
    #{inspect(report.name)} (#{inspect(report.module)}) did not replay identically: \
    #{report.callbacks} callbacks, #{report.equal} of #{report.outputs} outputs equal\
    #{if report.stopped, do: "; stopped: " <> report.stopped, else: ""}
    #{Enum.map_join(report.first_differences, "\n", &difference/1)}
    """)
  end

  defp difference(d) do
    "  callback #{d.callback} (#{inspect(d.input)}):\n" <>
      "    recorded: #{inspect(d.recorded, limit: 8, printable_limit: 120)}\n" <>
      "    replayed: #{inspect(d.replayed, limit: 8, printable_limit: 120)}"
  end
end
