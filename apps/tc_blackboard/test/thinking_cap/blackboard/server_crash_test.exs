defmodule ThinkingCap.Blackboard.ServerCrashTest do
  # Kills the node's blackboard server: must not run beside other tests.
  use ThinkingCap.BlackboardCase, async: false

  alias ThinkingCap.Blackboard.Core.Server
  alias ThinkingCap.Testing.Cluster

  test "killing the server loses no tuple, waiter or subscription", %{id: id} do
    for n <- 1..100, do: Blackboard.out({:kept, id, n})
    {:ok, sub} = Blackboard.subscribe({:news, id, :_})
    parent = self()
    spawn_link(fn -> send(parent, {:took, Blackboard.take({:work, id, :_})}) end)
    spawn_link(fn -> send(parent, {:read, Blackboard.rd({:notice, id})}) end)

    Cluster.wait_until(fn ->
      length(Enum.filter(Blackboard.waiters(), &(elem(&1.template, 1) == id))) == 2
    end)

    kill_server()
    # written while no server runs
    Blackboard.out({:work, id, :while_down})
    Blackboard.out({:news, id, :while_down})
    Cluster.wait_until(fn -> is_pid(Process.whereis(Server)) end)
    Blackboard.out({:notice, id})

    assert length(Blackboard.rd_all({:kept, id, :_})) == 100
    assert_receive {:took, {:ok, {:work, ^id, :while_down}}}, 2000
    assert_receive {:read, {:ok, {:notice, ^id}}}, 2000
    assert_receive {:blackboard, ^sub, {:news, ^id, :while_down}}
  end

  test "writers look for waiters while any process may be blocked, and only then", %{id: id} do
    alias ThinkingCap.Blackboard.Core.Waiters
    parent = self()
    # (no other test runs beside this module's)
    Cluster.wait_until(fn -> Blackboard.waiters() == [] end)
    refute Waiters.any?()

    # woken by a write
    spawn(fn -> send(parent, {:read, Blackboard.rd({:wc, id, :a})}) end)
    Cluster.wait_until(fn -> Waiters.any?() end)
    Blackboard.out({:wc, id, :a})
    assert_receive {:read, {:ok, _}}
    Cluster.wait_until(fn -> not Waiters.any?() end)

    # timed out
    assert {:error, :timeout} = Blackboard.take({:wc, id, :b}, 20)
    refute Waiters.any?()

    # killed while blocked
    taker = spawn(fn -> Blackboard.take({:wc, id, :c}) end)
    Cluster.wait_until(fn -> Waiters.any?() end)
    Process.exit(taker, :kill)
    Cluster.wait_until(fn -> not Waiters.any?() end)

    # and a write after all that wakes a new waiter
    spawn(fn -> send(parent, {:took, Blackboard.take({:wc, id, :d})}) end)
    Cluster.wait_until(fn -> Waiters.any?() end)
    Blackboard.out({:wc, id, :d})
    assert_receive {:took, {:ok, {:wc, ^id, :d}}}
  end

  test "subscribers are monitored again by the restarted server", %{id: id} do
    parent = self()

    pid =
      spawn(fn ->
        {:ok, ref} = Blackboard.subscribe({:mon, id})
        send(parent, {:ref, ref})
        Process.sleep(:infinity)
      end)

    assert_receive {:ref, ref}
    kill_server()
    Cluster.wait_until(fn -> is_pid(Process.whereis(Server)) end)
    Process.exit(pid, :kill)
    Cluster.wait_until(fn -> not Enum.any?(Blackboard.subscriptions(), &(&1.ref == ref)) end)
  end

  test "a waiter blocked before the crash is served by a tuple written after it", %{id: id} do
    task = Task.async(fn -> Blackboard.take({:after_restart, id}, 10_000) end)

    Cluster.wait_until(fn ->
      Enum.any?(Blackboard.waiters(), &(&1.template == {:after_restart, id}))
    end)

    kill_server()
    Cluster.wait_until(fn -> is_pid(Process.whereis(Server)) end)
    Blackboard.out({:after_restart, id})
    assert {:ok, {:after_restart, ^id}} = Task.await(task)
  end

  defp kill_server do
    pid = Process.whereis(Server)
    ref = Process.monitor(pid)
    Process.exit(pid, :kill)
    assert_receive {:DOWN, ^ref, :process, ^pid, :killed}
  end
end
