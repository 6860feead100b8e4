defmodule ThinkingCap.Blackboard.BatchSubscriptionTest do
  # Not async: one test kills the node's batch process.
  use ThinkingCap.BlackboardCase, async: false

  alias ThinkingCap.Blackboard.Core.{Batches, Tables}
  import ThinkingCap.Testing.Cluster, only: [wait_until: 1]

  # the lists taken for `ref`, one per notice, until `count` tuples came
  defp receive_lists(ref, count, timeout, acc \\ [])
  defp receive_lists(_ref, count, _timeout, acc) when count <= 0, do: Enum.reverse(acc)

  defp receive_lists(ref, count, timeout, acc) do
    receive do
      {:blackboard_held, ^ref} ->
        entries = Blackboard.take_held(ref)
        tuples = for {tuple, at} <- entries, is_integer(at), do: tuple
        assert length(tuples) == length(entries)
        receive_lists(ref, count - length(tuples), timeout, [tuples | acc])
    after
      timeout -> flunk("#{count} tuples missing; got #{inspect(Enum.reverse(acc), limit: 10)}")
    end
  end

  defp receive_tuples(ref, count, timeout \\ 2_000),
    do: ref |> receive_lists(count, timeout) |> Enum.concat()

  defp held(ref), do: :ets.select_count(Tables.batched(), [{{{ref, :_}, :_, :_}, [], [true]}])

  test "every tuple comes once, each writer's in order", %{id: id} do
    # room for all: writers in a burst outrun the subscriber
    {:ok, ref} = Blackboard.subscribe({:b, id, :_}, batch: true, max_batch: 16, max_queue: 4_000)
    writers = 4
    per = 500

    tasks =
      for w <- 1..writers do
        Task.async(fn -> for n <- 1..per, do: Blackboard.out({:b, id, {w, n}}) end)
      end

    Enum.each(tasks, &Task.await/1)
    Blackboard.out({:other, id, 0})

    got = receive_tuples(ref, writers * per)
    assert length(got) == writers * per

    for w <- 1..writers do
      assert for({:b, ^id, {^w, n}} <- got, do: n) == Enum.to_list(1..per)
    end

    refute_receive {:blackboard_held, ^ref}, 50
    refute_received {:blackboard, ^ref, _}
    assert Blackboard.dropped(ref) == 0
    assert Blackboard.take_held(ref) == []
    :ok = Blackboard.unsubscribe(ref)
  end

  test "a notice comes when max_batch tuples are held, else after max_delay_ms", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:c, id, :_}, batch: true, max_batch: 10, max_delay_ms: 300)
    for n <- 1..10, do: Blackboard.out({:c, id, n})

    # the tenth: at once
    assert_receive {:blackboard_held, ^ref}, 200
    assert Enum.map(Blackboard.take_held(ref), &elem(&1, 0)) == for(n <- 1..10, do: {:c, id, n})
    # three more wait for the timer
    for n <- 11..13, do: Blackboard.out({:c, id, n})
    refute_receive {:blackboard_held, ^ref}, 100
    assert_receive {:blackboard_held, ^ref}, 1_000
    assert Enum.map(Blackboard.take_held(ref), &elem(&1, 0)) == for(n <- 11..13, do: {:c, id, n})
    assert held(ref) == 0
    :ok = Blackboard.unsubscribe(ref)
  end

  test "one notice at a time: what is held waits for the take", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:o, id, :_}, batch: true, max_batch: 5, max_delay_ms: 20)
    for n <- 1..23, do: Blackboard.out({:o, id, n})
    assert_receive {:blackboard_held, ^ref}
    refute_receive {:blackboard_held, ^ref}, 100
    assert Enum.map(Blackboard.take_held(ref), &elem(&1, 0)) == for(n <- 1..23, do: {:o, id, n})
    :ok = Blackboard.unsubscribe(ref)
  end

  test "a single tuple is told of after max_delay_ms, stamped when it was written",
       %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:d, id, :_}, batch: true, max_delay_ms: 30)
    before = System.monotonic_time()
    Blackboard.out({:d, id, 1})
    later = System.monotonic_time()
    assert_receive {:blackboard_held, ^ref}, 1_000
    assert [{{:d, ^id, 1}, at}] = Blackboard.take_held(ref)
    assert before <= at and at <= later
    :ok = Blackboard.unsubscribe(ref)
  end

  test "take_held/1 takes what is held at any time, and only the subscriber's", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:fl, id, :_}, batch: true, max_delay_ms: 60_000)
    for n <- 1..5, do: Blackboard.out({:fl, id, n})
    assert Task.await(Task.async(fn -> Blackboard.take_held(ref) end)) == []
    assert Enum.map(Blackboard.take_held(ref), &elem(&1, 0)) == for(n <- 1..5, do: {:fl, id, n})
    assert held(ref) == 0
    assert Blackboard.take_held(ref) == []
    :ok = Blackboard.unsubscribe(ref)
    assert Blackboard.take_held(ref) == []
  end

  test "unbatched subscribers of the same tuples are served as before", %{id: id} do
    {:ok, batched} = Blackboard.subscribe({:e, id, :_}, batch: true, max_batch: 4)
    {:ok, plain} = Blackboard.subscribe({:e, id, :_})
    for n <- 1..10, do: Blackboard.out({:e, id, n})
    for n <- 1..10, do: assert_receive({:blackboard, ^plain, {:e, ^id, ^n}})
    assert receive_tuples(batched, 10) == for(n <- 1..10, do: {:e, id, n})
    refute_received {:blackboard, ^batched, _}
    refute_received {:blackboard_held, ^plain}

    assert [%{batch: %{max_batch: 4, max_delay_ms: 20}}] =
             for(s <- Blackboard.subscriptions(), s.ref == batched, do: s)

    assert [%{batch: false}] = for(s <- Blackboard.subscriptions(), s.ref == plain, do: s)
    :ok = Blackboard.unsubscribe(batched)
    :ok = Blackboard.unsubscribe(plain)
  end

  test "unsubscribe forgets the held tuples and flushes the notice received", %{id: id} do
    {:ok, ref} =
      Blackboard.subscribe({:f, id, :_}, batch: true, max_batch: 2, max_delay_ms: 60_000)

    for n <- 1..3, do: Blackboard.out({:f, id, n})
    assert_receive {:blackboard_held, ^ref}
    send(self(), {:blackboard_held, ref})
    :ok = Blackboard.unsubscribe(ref)
    refute_received {:blackboard_held, ^ref}
    assert held(ref) == 0
    Blackboard.out({:f, id, 4})
    refute_receive {:blackboard_held, ^ref}, 100
    assert Blackboard.dropped(ref) == nil
  end

  test "a restarted subscriber gets every tuple written after it subscribed again", %{id: id} do
    parent = self()

    subscriber = fn ->
      spawn(fn ->
        {:ok, ref} =
          Blackboard.subscribe({:g, id, :_}, batch: true, max_batch: 8, max_delay_ms: 50)

        send(parent, {:subscribed, self(), ref})
        forward(parent, ref)
      end)
    end

    first = subscriber.()
    assert_receive {:subscribed, ^first, ref1}
    for n <- 1..5, do: Blackboard.out({:g, id, n})
    # killed with its tuples held
    Process.exit(first, :kill)
    wait_until(fn -> Blackboard.dropped(ref1) == nil end)
    assert held(ref1) == 0

    second = subscriber.()
    assert_receive {:subscribed, ^second, ref2}
    for n <- 6..40, do: Blackboard.out({:g, id, n})
    assert forwarded(ref2, 35) == for(n <- 6..40, do: {:g, id, n})
    Process.exit(second, :kill)
  end

  defp forward(parent, ref) do
    receive do
      {:blackboard_held, ^ref} ->
        send(parent, {:forwarded, ref, Enum.map(Blackboard.take_held(ref), &elem(&1, 0))})
        forward(parent, ref)
    end
  end

  defp forwarded(_ref, count, acc \\ [])
  defp forwarded(_ref, count, acc) when count <= 0, do: acc

  defp forwarded(ref, count, acc) do
    receive do
      {:forwarded, ^ref, tuples} -> forwarded(ref, count - length(tuples), acc ++ tuples)
    after
      2_000 -> flunk("#{count} tuples missing")
    end
  end

  test "tuples held when the batch process dies are told of by its successor", %{id: id} do
    {:ok, ref} =
      Blackboard.subscribe({:h, id, :_}, batch: true, max_batch: 1000, max_delay_ms: 200)

    for n <- 1..20, do: Blackboard.out({:h, id, n})
    old = Process.whereis(Batches)
    Process.exit(old, :kill)
    wait_until(fn -> (pid = Process.whereis(Batches)) != nil and pid != old end)
    assert receive_tuples(ref, 20, 3_000) == for(n <- 1..20, do: {:h, id, n})
    for n <- 21..30, do: Blackboard.out({:h, id, n})
    assert receive_tuples(ref, 10) == for(n <- 21..30, do: {:h, id, n})
    :ok = Blackboard.unsubscribe(ref)
  end

  test "a position taken and never filled holds the lists up a second at most", %{id: id} do
    {:ok, ref} = Blackboard.subscribe({:k, id, :_}, batch: true, max_batch: 100, max_delay_ms: 20)
    Blackboard.out({:k, id, 1})
    assert receive_tuples(ref, 1) == [{:k, id, 1}]
    # a writer killed between taking its position and inserting its tuple
    :ets.update_counter(Tables.batches(), ref, {2, 1})
    Blackboard.out({:k, id, 3})
    assert_receive {:blackboard_held, ^ref}, 1_000
    assert Blackboard.take_held(ref) == []
    assert receive_tuples(ref, 1, 3_000) == [{:k, id, 3}]
    assert held(ref) == 0
    :ok = Blackboard.unsubscribe(ref)
  end

  describe "bounds" do
    test ":drop holds at most max_queue tuples for a subscriber that does not take",
         %{id: id} do
      {:ok, ref} =
        Blackboard.subscribe({:m, id, :_},
          batch: true,
          max_batch: 10,
          max_delay_ms: 5,
          max_queue: 50
        )

      for n <- 1..300, do: Blackboard.out({:m, id, n})
      assert_receive {:blackboard_held, ^ref}
      assert Blackboard.dropped(ref) == 250
      assert Enum.map(Blackboard.take_held(ref), &elem(&1, 0)) == for(n <- 1..50, do: {:m, id, n})
      # room again
      Blackboard.out({:m, id, 301})
      assert receive_tuples(ref, 1) == [{:m, id, 301}]
      :ok = Blackboard.unsubscribe(ref)
    end

    test ":disconnect ends the subscription when max_queue tuples are held", %{id: id} do
      {:ok, ref} =
        Blackboard.subscribe({:n, id, :_},
          batch: true,
          max_batch: 1000,
          max_delay_ms: 60_000,
          max_queue: 20,
          on_overflow: :disconnect
        )

      for n <- 1..25, do: Blackboard.out({:n, id, n})
      assert_receive {:blackboard_overflow, ^ref}
      assert Blackboard.dropped(ref) == nil
      assert held(ref) == 0
      assert Blackboard.take_held(ref) == []
    end
  end

  # a subscriber's `hold:` function (run by the writer)
  @doc false
  def as_held({_tag, _id, :boom}), do: raise("no")
  def as_held({tag, id, payload}), do: {:held, tag, id, :erlang.term_to_binary(payload)}

  test "hold: the writer holds what the subscriber's function makes of a tuple", %{id: id} do
    {:ok, ref} =
      Blackboard.subscribe({:h, id, :_},
        batch: true,
        max_batch: 3,
        hold: {__MODULE__, :as_held}
      )

    writer = Task.async(fn -> for p <- [1, :boom, 3], do: Blackboard.out({:h, id, p}) end)
    Task.await(writer)

    # the tuple itself when the function raised
    assert receive_tuples(ref, 3) == [
             {:held, :h, id, :erlang.term_to_binary(1)},
             {:h, id, :boom},
             {:held, :h, id, :erlang.term_to_binary(3)}
           ]

    assert [%{batch: %{hold: {__MODULE__, :as_held}}}] =
             for(s <- Blackboard.subscriptions(), s.ref == ref, do: s)

    :ok = Blackboard.unsubscribe(ref)
  end

  test "bad batch options are refused, naming the option" do
    assert_raise ArgumentError, ~r/bad subscribe\/2 option \{:batch, :yes\}/, fn ->
      Blackboard.subscribe({:a}, batch: :yes)
    end

    assert_raise ArgumentError, ~r/bad subscribe\/2 option \{:max_batch, 0\}/, fn ->
      Blackboard.subscribe({:a}, batch: true, max_batch: 0)
    end

    assert_raise ArgumentError, ~r/need batch: true/, fn ->
      Blackboard.subscribe({:a}, max_delay_ms: 10)
    end

    assert_raise ArgumentError, ~r/need batch: true/, fn ->
      Blackboard.subscribe({:a}, hold: {__MODULE__, :as_held})
    end

    assert_raise ArgumentError, ~r/bad subscribe\/2 option \{:hold, :as_held\}/, fn ->
      Blackboard.subscribe({:a}, batch: true, hold: :as_held)
    end
  end
end
