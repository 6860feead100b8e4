defmodule ThinkingCap.Runtime.SchedulingTest do
  # Changes the scheduling of this VM's threads (and puts it back).
  use ExUnit.Case, async: false

  alias ThinkingCap.Runtime.Scheduling

  @root System.cmd("id", ["-u"]) == {"0\n", 0}

  # schedulers at SCHED_FIFO 1, the I/O poller above them at 2
  defp realtime?(policies) do
    Enum.all?(policies, fn
      {name, policy} ->
        prio = if String.ends_with?(name, "_poller"), do: 2, else: 1
        match?(%{policy: :fifo, rt_priority: ^prio}, policy)
    end)
  end

  test "at start the runtime put the BEAM's schedulers at SCHED_FIFO 1 and its poller at 2" do
    policies = Scheduling.policies()
    names = Map.keys(policies)
    assert "1_scheduler" in names
    # the dirty CPU schedulers, which collect large processes' garbage, too
    assert "1_dirty_cpu_sch" in names
    assert Enum.any?(names, &String.ends_with?(&1, "_poller"))

    # as root (these machines, CI) real-time priority is granted
    if @root do
      assert realtime?(policies), inspect(policies)
    else
      assert {:error, _} = Scheduling.realtime(1)
    end
  end

  test "programs the BEAM starts (port programs, peer nodes) do not inherit real-time priority" do
    {out, 0} = System.cmd("sh", ["-c", "chrt -p $$"])
    assert out =~ "SCHED_OTHER", out
  end

  test "nice and realtime switch the policy both ways" do
    if @root do
      assert {:ok, _} = Scheduling.nice(-10)

      assert Enum.all?(
               Map.values(Scheduling.policies()),
               &match?(%{policy: :other, nice: -10}, &1)
             )

      assert {:ok, _} = Scheduling.realtime(1)
      assert realtime?(Scheduling.policies())
    else
      assert {:error, _} = Scheduling.nice(-10)
    end
  end

  test "busy_wait_off? reads the VM's flags" do
    expected = File.read!("/proc/#{System.pid()}/cmdline") =~ <<"-sbwt", 0, "none">>
    assert Scheduling.busy_wait_off?() == expected
  end
end
