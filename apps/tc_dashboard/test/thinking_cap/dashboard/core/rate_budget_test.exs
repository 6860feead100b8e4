defmodule ThinkingCap.Dashboard.Core.RateBudgetTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Core.RateBudget

  # feeds `n` messages spaced `gap_ms` apart from `t0`; returns the counts
  # of admitted and dropped messages, the budget and the clock
  defp feed(budget, n, gap_ms, t0) do
    Enum.reduce(1..n, {0, 0, budget, t0}, fn _, {ok, drop, b, t} ->
      case RateBudget.admit(b, t) do
        {:ok, b} -> {ok + 1, drop, b, t + gap_ms}
        {:drop, b} -> {ok, drop + 1, b, t + gap_ms}
      end
    end)
  end

  test "a burst is admitted, the surplus dropped" do
    {ok, drop, budget, _t} = feed(RateBudget.new(100, 200), 300, 0, 0)
    assert ok == 200
    assert drop == 100
    assert budget.dropped == 100
  end

  test "a steady client under the rate is never dropped" do
    {ok, drop, _budget, _t} = feed(RateBudget.new(100, 200), 2_000, 11, 0)
    assert {ok, drop} == {2_000, 0}
  end

  test "a flood is found out even when a token trickles in between its messages" do
    # 1,000 messages a second against a budget of 100: one in ten admitted
    {ok, _drop, budget, _t} = feed(RateBudget.new(100, 200), 3_000, 1, 0)
    assert ok > 200
    assert RateBudget.flooding?(budget, 2_000)
  end

  test "drops are forgiven once the client has paused long enough to refill" do
    {_ok, _drop, budget, t} = feed(RateBudget.new(100, 200), 300, 0, 0)
    assert budget.dropped == 100

    # a short pause does not refill the bucket: the count stands
    {:ok, budget} = RateBudget.admit(budget, t + 500)
    assert budget.dropped == 100

    # two seconds refill it: forgiven
    {:ok, budget} = RateBudget.admit(budget, t + 2_600)
    assert budget.dropped == 0
    refute RateBudget.flooding?(budget, 1)
  end

  test "an error reply on the first drop, then one every `every` drops" do
    {_ok, _drop, budget, t} = feed(RateBudget.new(100, 200), 201, 0, 0)
    assert {true, budget} = RateBudget.warn?(budget, 50)

    warnings =
      Enum.reduce(1..100, {0, budget}, fn _, {n, b} ->
        {:drop, b} = RateBudget.admit(b, t)

        case RateBudget.warn?(b, 50) do
          {true, b} -> {n + 1, b}
          {false, b} -> {n, b}
        end
      end)
      |> elem(0)

    assert warnings == 2
  end
end
