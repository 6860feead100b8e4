defmodule ThinkingCap.Blackboard.PropertyTest do
  @moduledoc false
  # PropEr (Debian erlang-proper) runs random operation sequences against the
  # blackboard and against a plain list model, and compares every result.
  use ExUnit.Case, async: false

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Blackboard.Template

  @tags [:prop_a, :prop_b]
  @robots [:r1, :r2]
  # values that tell an exact match from a loose one
  @values [0, 1, 1.0, %{a: 1}, %{}, {:_}, :"$1", [1, :_], "bin", :_]
  @keys [:k1, :k2]
  # every model tuple and template ends with this, so that wildcard templates
  # never see other tests' tuples
  @space :prop_space

  ## Generators

  defp gen_tuple,
    do: :proper_types.tuple([elements(@tags), elements(@robots), elements(@values), @space])

  defp gen_template do
    :proper_types.tuple([
      elements([:_ | @tags]),
      elements([:_ | @robots]),
      elements(@values),
      @space
    ])
  end

  defp elements(list), do: :proper_types.elements(list)

  ## The state machine (callbacks called by :proper_statem)

  @doc false
  def initial_state, do: %{seq: 0, tuples: []}

  @doc false
  def command(_state) do
    :proper_types.oneof([
      {:call, __MODULE__, :out, [gen_tuple()]},
      {:call, __MODULE__, :out_keyed, [gen_tuple(), elements(@keys)]},
      {:call, __MODULE__, :rdp, [gen_template()]},
      {:call, __MODULE__, :takep, [gen_template()]},
      {:call, __MODULE__, :take_now, [gen_template()]},
      {:call, __MODULE__, :rd_all, [gen_template()]}
    ])
  end

  @doc false
  def precondition(_state, _call), do: true

  @doc false
  def next_state(state, _result, {:call, _, :out, [tuple]}), do: add(state, tuple, nil)

  def next_state(state, _result, {:call, _, :out_keyed, [tuple, key]}) do
    state
    |> Map.update!(:tuples, fn ts -> Enum.reject(ts, &(elem(&1, 2) == key)) end)
    |> add(tuple, key)
  end

  def next_state(state, _result, {:call, _, take, [template]}) when take in [:takep, :take_now] do
    case first(state, template) do
      nil -> state
      entry -> %{state | tuples: List.delete(state.tuples, entry)}
    end
  end

  def next_state(state, _result, _read), do: state

  @doc false
  def postcondition(_state, {:call, _, out, _}, result) when out in [:out, :out_keyed],
    do: result == :ok

  def postcondition(state, {:call, _, op, [template]}, result) when op in [:rdp, :takep] do
    case first(state, template) do
      nil -> result == :none
      {_, tuple, _} -> result === {:ok, tuple}
    end
  end

  def postcondition(state, {:call, _, :take_now, [template]}, result) do
    case first(state, template) do
      nil -> result == {:error, :timeout}
      {_, tuple, _} -> result === {:ok, tuple}
    end
  end

  def postcondition(state, {:call, _, :rd_all, [template]}, result) do
    expected = for {_, t, _} <- state.tuples, model_match?(template, t), do: t
    # as multisets, exactly: sorting alone would order 1 and 1.0 as equals
    Enum.frequencies(result) === Enum.frequencies(expected)
  end

  defp add(state, tuple, key),
    do: %{state | seq: state.seq + 1, tuples: state.tuples ++ [{state.seq, tuple, key}]}

  # The blackboard reads and takes the oldest tuple of a tag and robot id;
  # tags and ids in term order.
  defp first(state, template) do
    state.tuples
    |> Enum.filter(fn {_, t, _} -> model_match?(template, t) end)
    |> Enum.min_by(fn {seq, t, _} -> {elem(t, 0), elem(t, 1), seq} end, fn -> nil end)
  end

  defp model_match?(template, tuple) do
    tuple_size(template) == tuple_size(tuple) and
      Enum.all?(Enum.zip(Tuple.to_list(template), Tuple.to_list(tuple)), fn {p, v} ->
        p === :_ or p === v
      end)
  end

  ## Operations under test

  @doc false
  def out(tuple), do: Blackboard.out(tuple)
  @doc false
  def out_keyed(tuple, key), do: Blackboard.out(tuple, key: {__MODULE__, key})
  @doc false
  def rdp(template), do: Blackboard.rdp(template)
  @doc false
  def takep(template), do: Blackboard.takep(template)
  @doc false
  def take_now(template), do: Blackboard.take(template, 0)
  @doc false
  def rd_all(template), do: Blackboard.rd_all(template)

  defp clear do
    for t <- Blackboard.rd_all({:_, :_, :_, @space}), do: {:ok, ^t} = Blackboard.takep(exact(t))
    [] = Blackboard.rd_all({:_, :_, :_, @space})
  end

  # A template selecting exactly `tuple`, even when it holds :_ itself.
  defp exact(tuple), do: {:spec, [{:"$1", [{:"=:=", :"$1", {:const, tuple}}], [true]}]}

  ## Properties

  test "random operation sequences agree with a list model" do
    # a subscriber to one tag: writes of :prop_a wake it, so they are staged
    # and settled around a yield, while writes of :prop_b are stored at once
    me = self()

    listener =
      spawn_link(fn ->
        {:ok, ref} = Blackboard.subscribe({:prop_a, :_, :_, @space}, max_queue: 100_000)
        send(me, :listening)
        drain(ref)
      end)

    assert_receive :listening

    property =
      :proper.forall(:proper_statem.commands(__MODULE__), fn commands ->
        clear()
        {history, state, result} = :proper_statem.run_commands(__MODULE__, commands)
        clear()

        :proper.whenfail(
          fn -> IO.puts("history: #{inspect(history)}
state: #{inspect(state)}
result: #{inspect(result)}") end,
          fn -> result == :ok end
        )
      end)

    assert check(property, 300) == true
    send(listener, {:count, self()})
    assert_receive {:heard, n}
    assert n > 0
  end

  defp drain(ref, heard \\ 0) do
    receive do
      {:blackboard, ^ref, _tuple} -> drain(ref, heard + 1)
      {:count, from} -> send(from, {:heard, heard})
    end
  end

  test "a compiled template matches exactly the tuples a naive matcher does" do
    gen = :proper_types.tuple([gen_template(), gen_tuple()])

    property =
      :proper.forall(gen, fn {template, tuple} ->
        Template.matches?(Template.compile(template), tuple) == model_match?(template, tuple)
      end)

    assert check(property, 2000) == true
  end

  # true, or the shrunk counterexample
  defp check(property, runs) do
    :proper.quickcheck(property, [
      {:numtests, runs},
      {:on_output, fn _format, _args -> :ok end},
      :long_result
    ])
  end
end
