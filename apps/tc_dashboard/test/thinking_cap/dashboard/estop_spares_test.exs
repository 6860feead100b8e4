defmodule ThinkingCap.Dashboard.EstopSparesTest do
  # The E-stop port's spare descriptors, when the node has no other left
  # (ThinkingCap.Dashboard.Core.EstopListener): Linux refuses an accept
  # for want of a descriptor whether or not a connection waits, and
  # another part of the node (the web server's watchdog restarting yaws)
  # may take a descriptor the moment a spare frees it. Here an accept
  # function stands in for the socket and for that thief, so the race
  # the fault test meets now and then happens every time.
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Core.EstopListener

  # spares as the listener holds them: /dev/null, open
  defp spares(n) do
    for _ <- 1..n do
      {:ok, file} = File.open("/dev/null", [:read])
      file
    end
  end

  defp open?(file), do: Process.alive?(file)

  # an accept that answers `answers` in turn, recording how it was called
  defp accept(answers) do
    {:ok, agent} = Agent.start_link(fn -> {answers, []} end)

    fun = fn how ->
      Agent.get_and_update(agent, fn {[answer | rest], calls} ->
        {answer, {rest, [how | calls]}}
      end)
    end

    {fun, fn -> agent |> Agent.get(&elem(&1, 1)) |> Enum.reverse() end}
  end

  defp soon, do: System.monotonic_time(:millisecond) + 2_000

  test "the descriptor a spare freed is taken by another part of the node: the next spare goes" do
    [a, b, c, d] = spares(4)
    # the thief takes the first two descriptors freed; a connection waits
    {accept, calls} = accept([:no_descriptor, :no_descriptor, {:ok, :socket}])

    assert {{:ok, :socket}, [^d]} = EstopListener.accept_releasing(accept, [a, b, c, d], soon())
    assert calls.() == [:now, :now, :now]
    refute Enum.any?([a, b, c], &open?/1)
    assert open?(d)
  end

  test "nobody connecting: one spare given up, the accept does not wait" do
    [a, b] = spares(2)
    {accept, calls} = accept([:none])

    assert {:none, [^b]} = EstopListener.accept_releasing(accept, [a, b], soon())
    assert calls.() == [:now]
    refute open?(a)
    assert open?(b)
  end

  test "every spare taken: it waits for a free descriptor, until its deadline" do
    [a, b] = spares(2)
    {accept, calls} = accept([:no_descriptor, :no_descriptor, :no_descriptor, {:ok, :late}])

    assert {{:ok, :late}, []} = EstopListener.accept_releasing(accept, [a, b], soon())
    assert calls.() == [:now, :now, :wait, :wait]

    # the deadline passed: nobody is served, the listener turns again
    {accept, _calls} = accept(List.duplicate(:no_descriptor, 10))
    past = System.monotonic_time(:millisecond) - 1
    assert {:none, []} = EstopListener.accept_releasing(accept, spares(1), past)
  end
end
