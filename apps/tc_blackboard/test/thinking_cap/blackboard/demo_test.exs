defmodule ThinkingCap.Blackboard.DemoTest do
  @moduledoc false
  # Runs the blackboard demo (mix tc.demo) in its own
  # distributed VM and checks what it prints.
  use ExUnit.Case, async: true

  @moduletag timeout: 120_000

  test "the demo streams poses from a second node and takes its jobs" do
    root = Path.expand("../../../../..", __DIR__)
    name = "tc_demo_test_#{System.unique_integer([:positive])}@127.0.0.1"

    {output, status} =
      System.cmd("elixir", ["--name", name, "-S", "mix", "tc.demo", "--seconds", "3"],
        cd: root,
        env: [{"MIX_ENV", "test"}],
        stderr_to_stdout: true
      )

    assert status == 0, output
    assert output =~ ~r/blackboard demo: this node tc_demo_test_\d+@127.0.0.1, sensor node \S+/
    status_lines = Regex.scan(~r/poses received (\d+), .*; jobs taken (\d+);/, output)
    assert length(status_lines) == 3, output
    [_, poses, jobs] = List.last(status_lines)
    # 10 Hz poses and a job a second, written on the other node
    assert String.to_integer(poses) >= 15
    assert String.to_integer(jobs) >= 2
  end

  test "the demo refuses to run on a node that is not distributed" do
    root = Path.expand("../../../../..", __DIR__)

    {output, status} =
      System.cmd("mix", ["tc.demo", "--seconds", "1"],
        cd: root,
        env: [{"MIX_ENV", "test"}],
        stderr_to_stdout: true
      )

    assert status != 0
    assert output =~ "needs a distributed node"
  end
end
