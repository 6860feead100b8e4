defmodule ThinkingCap.Blackboard.Assertions do
  @moduledoc """
  ExUnit assertions over the blackboard, for testing modules that talk
  through it.

      import ThinkingCap.Blackboard.Assertions

      test "the controller stops on a bump" do
        Blackboard.out({:bumper, :r1, %{pressed: true}})
        assert {:cmd_vel, :r1, %{v: +0.0}} = assert_tuple({:cmd_vel, :r1, :_})
      end

  Failure messages list the tuples of the same tag that *are* there.
  """

  alias ThinkingCap.Blackboard

  @doc """
  Waits up to `timeout` ms for a tuple matching `template` and returns it;
  fails the test if none appears.
  """
  @spec assert_tuple(Blackboard.template(), timeout()) :: tuple()
  def assert_tuple(template, timeout \\ 1000) do
    case Blackboard.rd(template, timeout) do
      {:ok, tuple} ->
        tuple

      {:error, :timeout} ->
        ExUnit.Assertions.flunk(
          "no tuple matching #{inspect(template)} on the blackboard within #{timeout} ms" <>
            nearby(template)
        )
    end
  end

  @doc """
  Fails the test if a tuple matching `template` is on the blackboard, now
  or (with a `timeout`) at any time in the next `timeout` ms.
  """
  @spec refute_tuple(Blackboard.template(), non_neg_integer()) :: :ok
  def refute_tuple(template, timeout \\ 0) do
    case Blackboard.rd(template, timeout) do
      {:error, :timeout} ->
        :ok

      {:ok, tuple} ->
        ExUnit.Assertions.flunk(
          "expected no tuple matching #{inspect(template)}, found #{inspect(tuple)}"
        )
    end
  end

  @doc """
  Waits up to `timeout` ms for the calling process to be sent a tuple for
  subscription `ref` that matches `template`, and returns it.
  """
  @spec assert_delivered(reference(), Blackboard.template(), timeout()) :: tuple()
  def assert_delivered(ref, template, timeout \\ 1000) do
    compiled = Blackboard.Template.compile(template)
    deadline = System.monotonic_time(:millisecond) + timeout
    await_delivery(ref, compiled, deadline, template, timeout)
  end

  defp await_delivery(ref, compiled, deadline, template, timeout) do
    remaining = max(deadline - System.monotonic_time(:millisecond), 0)

    receive do
      {:blackboard, ^ref, tuple} ->
        if Blackboard.Template.matches?(compiled, tuple),
          do: tuple,
          else: await_delivery(ref, compiled, deadline, template, timeout)
    after
      remaining ->
        ExUnit.Assertions.flunk(
          "no tuple matching #{inspect(template)} delivered within #{timeout} ms"
        )
    end
  end

  defp nearby(template)
       when is_tuple(template) and tuple_size(template) > 0 and elem(template, 0) != :spec do
    wildcard = List.to_tuple([elem(template, 0) | List.duplicate(:_, tuple_size(template) - 1)])

    case Blackboard.rd_all(wildcard) do
      [] ->
        "; there is no tuple of that tag and arity"

      others ->
        "; tuples of that tag and arity:\n" <>
          Enum.map_join(Enum.take(others, 10), "\n", &("  " <> inspect(&1)))
    end
  end

  defp nearby(_template), do: ""
end
