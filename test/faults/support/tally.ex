defmodule ThinkingCap.FaultSuite.Tally do
  @moduledoc false
  # What the fault-injection suite counts for its summary line: faults
  # injected, faults survived (everything checked after it held), tuples
  # lost, and the longest uncommanded time of a robot's activity.

  @table __MODULE__

  def start do
    if :ets.whereis(@table) == :undefined do
      :ets.new(@table, [:named_table, :public, :set])
      :ets.give_away(@table, Process.whereis(:init), nil)
    end

    :ets.insert(@table, [{:injected, 0}, {:survived, 0}, {:tuples_lost, 0}, {:uncommanded, 0.0}])
    :ok
  end

  @doc "A fault is about to be injected."
  def injected, do: :ets.update_counter(@table, :injected, 1)

  @doc """
  The fault was survived: called at the end of a test, after its checks.
  `tuples_lost` and `uncommanded_ms` are what the test measured.
  """
  def survived(opts \\ []) do
    :ets.update_counter(@table, :survived, 1)
    :ets.update_counter(@table, :tuples_lost, Keyword.get(opts, :tuples_lost, 0))
    uncommanded(Keyword.get(opts, :uncommanded_ms, 0.0))
  end

  @doc "Records a measured uncommanded time (kept also when the test fails later)."
  def uncommanded(ms) do
    [{:uncommanded, worst}] = :ets.lookup(@table, :uncommanded)
    if ms > worst, do: :ets.insert(@table, {:uncommanded, ms * 1.0})
    :ok
  end

  @doc "Records tuples found lost (kept also when the test fails later)."
  def lost(n), do: :ets.update_counter(@table, :tuples_lost, n)

  def summary_line do
    get = fn key -> :ets.lookup_element(@table, key, 2) end

    "faults: injected=#{get.(:injected)} survived=#{get.(:survived)} " <>
      "tuples_lost=#{get.(:tuples_lost)} max_uncommanded_ms=#{Float.round(get.(:uncommanded), 1)}"
  end
end
