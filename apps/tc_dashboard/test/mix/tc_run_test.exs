defmodule Mix.Tasks.Tc.RunTest do
  @moduledoc false
  # Runs the README's main job (mix tc.run, what bin/run execs) in its own
  # VM and checks what it prints: the simulated robot wanders the office.
  use ExUnit.Case, async: true

  @moduletag timeout: 120_000

  test "the main job puts a simulated robot in the office world and it sets off on its patrol" do
    root = Path.expand("../../../..", __DIR__)
    assert File.exists?(Path.join(root, "priv/examples/office_sim.adf"))

    {output, status} =
      System.cmd(
        "mix",
        ~w(tc.run --seconds 4 --port 0 --rosbridge-port 0 --estop-port 0 --foxglove-port 0),
        cd: root,
        env: [
          {"MIX_ENV", "test"},
          {"ELIXIR_ERL_OPTIONS", "+sbwt none +sbwtdcpu none +sbwtdio none"}
        ],
        stderr_to_stdout: true
      )

    assert status == 0, output
    assert output =~ "robot :r1 in office.wdf"
    assert output =~ "base (ThinkingCap.Sim.Robot)"
    # the dashboard's URL, with its access token, for the user to open
    assert output =~ ~r"dashboard: http://127\.0\.0\.1:\d+/\?token=[\w-]{16,}"
    # and the port that only engages E-stops
    assert output =~ ~r"E-stop: curl -X POST http://127\.0\.0\.1:\d+/estop"
    # and the Foxglove WebSocket endpoint, with the same token
    assert output =~ ~r"foxglove: ws://127\.0\.0\.1:\d+/\?token=[\w-]{16,}"

    poses =
      for [x, y] <-
            Regex.scan(~r/ pose \((-?[\d.]+), (-?[\d.]+), /, output, capture: :all_but_first),
          do: {String.to_float(x), String.to_float(y)}

    assert length(poses) == 4, output
    # it starts at the dock (1, 1) and drives away from it, localized,
    # towards the first waypoint of its patrol
    {x, y} = List.last(poses)
    assert abs(x - 1.0) + abs(y - 1.0) > 0.2, output
    assert output =~ ~r/estimate \(/
    assert output =~ "plan moving :lab_bench"
    assert output =~ ~r/behaviours \w+=/
    # the cycle keeps commanding it
    assert output =~ ~r/cycle \d+ cycles/
  end
end
