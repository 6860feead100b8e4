defmodule ThinkingCap.Runtime.SchedulingTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Runtime.Scheduling

  test "the runtime raised the BEAM's scheduler and poller threads at start" do
    priorities = Scheduling.priorities()
    names = Map.keys(priorities)
    assert "1_scheduler" in names
    assert Enum.any?(names, &String.ends_with?(&1, "_poller"))

    # as root (these machines, CI) the configured nice -10 is granted
    if System.cmd("id", ["-u"]) == {"0\n", 0} do
      assert Enum.all?(Map.values(priorities), &(&1 == -10)), inspect(priorities)
    else
      assert {:error, _} = Scheduling.raise_priority(-10)
    end
  end
end
