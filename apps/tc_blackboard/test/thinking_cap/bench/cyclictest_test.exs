defmodule ThinkingCap.Bench.CyclictestTest do
  # cyclictest (rt-tests, which bin/setup installs) is the machine's
  # reference in the benchmarks and the fault tests
  use ExUnit.Case, async: false

  alias ThinkingCap.Bench.Cyclictest

  test "start/2 returns once cyclictest measures: stopped at once, it reports its wake-ups" do
    assert System.find_executable("cyclictest"),
           "cyclictest is missing: bin/setup installs rt-tests"

    # a fault window can be a few milliseconds: stopped before its threads
    # had woken, cyclictest reported a worst latency of 0 (or none), read
    # as a machine that had not stalled
    for _ <- 1..3 do
      probe = Cyclictest.start(60, 1_000)
      assert %{max: max, p50: p50, over: over} = Cyclictest.stop(probe)
      assert is_integer(max) and max > 0
      assert is_integer(p50) and p50 <= max
      assert over >= 0
    end
  end
end
