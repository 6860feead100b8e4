defmodule ThinkingCap.Blackboard.IndexFlagsTest do
  # A write looks for tag-only, arity-only and match-spec subscriptions only
  # while the index flags say some exist. Not async: the flags are the
  # node's, and a test running beside this one could raise them.
  use ThinkingCap.BlackboardCase, async: false

  alias ThinkingCap.Blackboard.Core.Tables

  defp subscriber(template) do
    test = self()

    pid =
      spawn(fn ->
        {:ok, ref} = Blackboard.subscribe(template)
        send(test, {:subscribed, self(), ref})
        receive do: (:never -> :ok)
      end)

    assert_receive {:subscribed, ^pid, ref}
    {pid, ref}
  end

  test "a tag's flag is up from subscribe until its bucket's last subscription is gone" do
    {a, b} = ThinkingCap.Test.Buckets.two_tags_in_a_free_bucket(:flag)
    refute Tables.tag_indexed?(3, a)

    {:ok, on_a} = Blackboard.subscribe({a, :_, :_})
    assert Tables.tag_indexed?(3, a)
    # one flag per bucket: b's writes look too, and find nothing of theirs
    assert Tables.tag_indexed?(3, b)

    {_pid, _on_b} = subscriber({b, :_, :_})
    {pid, _on_b2} = subscriber({b, :_, :_})
    :ok = Blackboard.unsubscribe(on_a)
    assert Tables.tag_indexed?(3, a)

    # a dead subscriber's subscription goes with it (the server cleans up)
    Process.exit(pid, :kill)
    ThinkingCap.Testing.Cluster.wait_until(fn -> length(subscriptions_of(b)) == 1 end)
    assert Tables.tag_indexed?(3, b)

    [%{ref: last}] = subscriptions_of(b)
    :ok = Blackboard.unsubscribe(last)
    refute Tables.tag_indexed?(3, a)

    # and a write to the tag finds, and sends, nothing
    Blackboard.out({a, 1, :after})
    refute_received {:blackboard, _, {^a, 1, :after}}
  end

  test "arity-only and match-spec flags each follow their own subscriptions", %{id: id} do
    # the subscriptions of earlier tests' processes go when the server has
    # handled their exits
    ThinkingCap.Testing.Cluster.wait_until(fn -> Tables.wide_indexed() == {false, false} end)

    {:ok, any} = Blackboard.subscribe({:_, id, :_})
    assert Tables.wide_indexed() == {true, false}

    {:ok, spec} = Blackboard.subscribe({:spec, [{{:_, id, :"$1"}, [{:>, :"$1", 5}], [true]}]})
    assert Tables.wide_indexed() == {true, true}

    Blackboard.out({:wide, id, 9})
    assert_receive {:blackboard, ^any, {:wide, ^id, 9}}
    assert_receive {:blackboard, ^spec, {:wide, ^id, 9}}

    :ok = Blackboard.unsubscribe(any)
    assert Tables.wide_indexed() == {false, true}
    :ok = Blackboard.unsubscribe(spec)
    assert Tables.wide_indexed() == {false, false}
    # unsubscribing twice lowers nothing twice
    :ok = Blackboard.unsubscribe(spec)
    assert Tables.wide_indexed() == {false, false}
  end

  test "the tables' owner answers a call it does not know without dying" do
    owner = Process.whereis(Tables)
    assert GenServer.call(Tables, :nonsense) == {:error, :unknown_call}
    assert GenServer.call(Tables, {:count, {:nonsense}, 1}) == {:error, :unknown_index}
    assert GenServer.call(Tables, {:count, :spec, 5}) == {:error, :unknown_call}
    assert Process.whereis(Tables) == owner
  end

  defp subscriptions_of(tag),
    do: Enum.filter(Blackboard.subscriptions(), &match?({^tag, :_, :_}, &1.template))
end
