defmodule Mix.Tasks.Tc.Run do
  @shortdoc "Runs the main job (bin/run): the office world with a simulated robot"
  @moduledoc """
  Runs ThinkingCap's main job: the example office world
  (`priv/examples/office.wdf`) with one simulated robot
  (`priv/examples/office_robot.rdf`), started from
  `priv/examples/office_sim.adf` by the runtime, in real time. Prints a
  status line a second: simulated time, the robot's true and estimated
  poses, its plan and waypoint, the active behaviours, its nearest
  obstacle, bumper, and the control cycle's timing. The ADF enables the web
  dashboard: its URL, with the access token, is printed at start; open it
  to watch the robot and drive it by hand.

      mix tc.run [--adf PATH] [--seconds N] [--port P] [--rosbridge-port P] [--foxglove-port P]
                 [--estop-port P] [--token-file PATH] [--record DIR]

  `--port`, `--rosbridge-port`, `--foxglove-port` and `--estop-port` override the ADF's
  dashboard ports (0: any free port); the Foxglove endpoint's URL
  (`ThinkingCap.Dashboard.Foxglove`) is printed beside the dashboard's; `--token-file` gives the access token (a file its owner
  alone may read) instead of a new one. `--record DIR` records the robot's
  tuples into MCAP files in DIR (`ThinkingCap.BlackBox.Recorder`): it
  turns on the ADF's `record:` section, with its other keys as the ADF
  gives them.

  `bin/run` does the set-up and starts it.
  """
  use Mix.Task

  alias ThinkingCap.{Blackboard, Runtime}
  alias ThinkingCap.Tuples
  require Tuples

  @impl true
  def run(args) do
    {opts, _rest} =
      OptionParser.parse!(args,
        strict: [
          seconds: :integer,
          adf: :string,
          port: :integer,
          rosbridge_port: :integer,
          foxglove_port: :integer,
          estop_port: :integer,
          token_file: :string,
          record: :string
        ]
      )

    Mix.Task.run("app.start")
    adf_path = opts[:adf] || Path.join(root(), "priv/examples/office_sim.adf")

    adf =
      case ThinkingCap.Config.read(adf_path) do
        {:ok, adf} -> adf |> dashboard_ports(opts) |> record(opts[:record])
        {:error, errors} -> Mix.raise(ThinkingCap.Config.format_errors(errors))
      end

    case Runtime.start(adf) do
      {:ok, modules} ->
        IO.puts(
          "thinkingcap: #{Path.relative_to_cwd(adf_path)}: robot #{inspect(adf.robot)} in " <>
            "#{Path.basename(adf.wdf || "?")}; modules " <>
            Enum.map_join(modules, ", ", &"#{&1.name} (#{inspect(&1.module)})")
        )

      {:error, failed} ->
        Mix.raise("could not start #{adf_path}: #{inspect(failed)}")
    end

    if adf.record[:enabled], do: IO.puts("record: #{Path.expand(adf.record.dir)}")

    if adf.dashboard[:enabled] do
      case ThinkingCap.Dashboard.await(10_000) do
        {:ok, info} ->
          IO.puts("dashboard: #{info.url}")

          if info.rosbridge_port,
            do:
              IO.puts("rosbridge: ws://#{info.host}:#{info.rosbridge_port}/?token=#{info.token}")

          foxglove = ThinkingCap.Dashboard.Foxglove.url(info)
          if foxglove, do: IO.puts("foxglove: #{foxglove}")

          if info.estop_port,
            do: IO.puts("E-stop: curl -X POST http://#{info.host}:#{info.estop_port}/estop")

        {:error, :timeout} ->
          IO.puts("dashboard: did not start (see the log)")
      end
    end

    report(adf.robot, opts[:seconds])
    # the VM halts when the task returns: the recording's last file is
    # closed first, with its summary (a stop by signal closes it too)
    if adf.record[:enabled], do: ThinkingCap.BlackBox.stop(adf.robot)
  end

  defp dashboard_ports(adf, opts) do
    overrides =
      opts
      |> Keyword.take([:port, :rosbridge_port, :foxglove_port, :estop_port, :token_file])
      |> Keyword.update(:token_file, nil, &Path.expand/1)
      |> Enum.reject(fn {_key, value} -> value == nil end)

    %{adf | dashboard: Map.merge(adf.dashboard, Map.new(overrides))}
  end

  # the recorder starts from the ADF's announcement (ThinkingCap.BlackBox)
  defp record(adf, nil), do: adf
  defp record(adf, dir), do: %{adf | record: Map.merge(adf.record, %{enabled: true, dir: dir})}

  defp report(_robot, 0), do: :ok

  defp report(robot, left) do
    Process.sleep(1000)

    if ThinkingCap.Runtime.Shutdown.begun?() do
      # the node is stopping (SIGTERM, Ctrl-C): the robot is stopped; the
      # VM ends when its applications are down
      Process.sleep(:infinity)
    else
      IO.puts(status_line(robot))
      report(robot, left && left - 1)
    end
  end

  defp status_line(robot) do
    truth = latest(Tuples.sim_pose(robot))
    odom = latest(Tuples.reading(:odom, robot))
    laser = latest(Tuples.reading(:laser, robot))
    bumper = latest(Tuples.reading(:bumper, robot))
    timing = Runtime.timing() |> Map.get(:base)

    estimate = latest(Tuples.pose(robot))
    plan = latest(Tuples.plan(robot))
    activation = latest(Tuples.activation(robot))

    [
      "t=#{fmt(truth[:stamp])} s",
      "pose #{pose(truth[:pose])}",
      if(estimate[:pose], do: "estimate #{pose(estimate.pose)}", else: "odom #{pose(odom[:pose])}"),
      if(plan[:state], do: "plan #{plan.state} #{inspect(plan[:waypoint])}"),
      if(activation != %{}, do: "behaviours #{behaviours(activation)}"),
      "nearest #{fmt(laser[:ranges] && Enum.min(laser.ranges))} m",
      "bumper #{if bumper[:pressed], do: "pressed", else: "free"}",
      "cycle #{timing_text(timing)}"
    ]
    |> Enum.reject(&is_nil/1)
    |> Enum.join(", ")
  end

  defp latest(template) do
    case Blackboard.rdp(template) do
      {:ok, Tuples.reading(_, _, payload)} -> payload
      :none -> %{}
    end
  end

  defp timing_text(%{cycles: n, fallbacks: f} = t),
    do: "#{n} cycles, #{f} fallbacks, jitter mean #{fmt(get_in(t, [:jitter_us, :mean]))} µs"

  defp timing_text(_), do: "-"

  # the active behaviours, most active first
  defp behaviours(activation) do
    activation
    |> Enum.filter(fn {_b, a} -> is_number(a) and a >= 0.05 end)
    |> Enum.sort_by(fn {_b, a} -> -a end)
    |> Enum.map_join(" ", fn {b, a} -> "#{b}=#{fmt(a)}" end)
  end

  defp pose({x, y, th}), do: "(#{fmt(x)}, #{fmt(y)}, #{fmt(th)})"
  defp pose(_), do: "-"

  defp fmt(nil), do: "-"
  defp fmt(x) when is_number(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)

  defp root do
    cwd = File.cwd!()
    if File.dir?(Path.join(cwd, "apps")), do: cwd, else: Path.expand("../..", cwd)
  end
end
