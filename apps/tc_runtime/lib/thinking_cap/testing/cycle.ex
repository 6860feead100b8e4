defmodule ThinkingCap.Testing.Cycle do
  @moduledoc """
  ExUnit helpers for tests of periodic modules: wait for the releases and
  the applied commands of an activity (`ThinkingCap.Cycle`). The calling
  process must own the activity or have called `ThinkingCap.Cycle.subscribe/1`.

      :ok = ThinkingCap.Cycle.subscribe(:control)
      assert %{kind: :fresh, command: {:vel, _, _}} = ThinkingCap.Testing.Cycle.applied(:control)
  """
  import ExUnit.Assertions, only: [flunk: 1]

  @doc "The next release of activity `name` (for its owner), or a test failure."
  @spec release(atom(), timeout()) :: ThinkingCap.Cycle.release()
  def release(name, timeout \\ 2000) do
    receive do
      {:tc_cycle, :release, ^name, release} -> release
    after
      timeout -> flunk("no release of #{inspect(name)} within #{timeout} ms")
    end
  end

  @doc "The next command applied for activity `name`, or a test failure."
  @spec applied(atom(), timeout()) :: map()
  def applied(name, timeout \\ 2000) do
    receive do
      {:tc_cycle, :applied, ^name, event} -> event
    after
      timeout -> flunk("nothing applied for #{inspect(name)} within #{timeout} ms")
    end
  end

  @doc """
  Skips applied commands of `name` until one for which `fun` is true, and
  returns it; a test failure if none comes within `timeout` ms in all
  (commands that keep coming, none of them the one, do not extend it).
  """
  @spec applied_until(atom(), (map() -> boolean()), timeout()) :: map()
  def applied_until(name, fun, timeout \\ 5000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    skip_until(name, fun, deadline, timeout)
  end

  defp skip_until(name, fun, deadline, timeout) do
    left = max(deadline - System.monotonic_time(:millisecond), 0)

    receive do
      {:tc_cycle, :applied, ^name, event} ->
        if fun.(event), do: event, else: skip_until(name, fun, deadline, timeout)
    after
      left -> flunk("no command applied for #{inspect(name)} was the one within #{timeout} ms")
    end
  end
end
