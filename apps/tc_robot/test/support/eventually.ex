defmodule ThinkingCap.Robot.Test.Eventually do
  @moduledoc false
  # Retries an assertion until it holds, for tests of things that happen
  # on their own time (a serial line, an emulated robot).

  @doc "Runs `fun` until it stops raising an assertion or match error, for up to `timeout` ms."
  def eventually(fun, timeout \\ 5000) do
    retry(fun, System.monotonic_time(:millisecond) + timeout)
  end

  defp retry(fun, deadline) do
    fun.()
  rescue
    e in [ExUnit.AssertionError, MatchError] ->
      if System.monotonic_time(:millisecond) > deadline, do: reraise(e, __STACKTRACE__)
      Process.sleep(20)
      retry(fun, deadline)
  end
end
