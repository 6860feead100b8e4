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
