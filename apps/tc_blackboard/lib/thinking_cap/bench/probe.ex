defmodule ThinkingCap.Bench.Probe do
  @moduledoc """
  Processes benchmarks start on their own node or on peer nodes to time
  message paths. A probe reads a timestamp in nanoseconds (os clock, shared
  by every node of the machine) from what it receives and reports the
  latency, `{:latency, tag, ns}`, to `report_to`.
  """

  alias ThinkingCap.Blackboard

  @doc "Now, in nanoseconds, on the clock all local nodes share."
  @spec now_ns() :: integer()
  def now_ns, do: :os.system_time(:nanosecond)

  @doc """
  Subscribes to `template` and reports the latency of every tuple whose
  last element is a send time from `now_ns/0` (tag `tag`), and of every
  `{:raw, sent_ns}` sent to it directly (tag `:send`): the same receiving
  process for both paths. With `report?: false` it only receives (a
  bystander subscription).
  """
  @spec subscriber(Blackboard.template(), pid(), term(), boolean()) :: pid()
  def subscriber(template, report_to, tag, report? \\ true) do
    parent = self()

    pid =
      spawn(fn ->
        {:ok, ref} = Blackboard.subscribe(template)
        send(parent, {:probe_ready, self()})
        subscriber_loop(ref, report_to, tag, report?)
      end)

    receive do
      {:probe_ready, ^pid} -> pid
    end
  end

  defp subscriber_loop(ref, report_to, tag, report?) do
    receive do
      {:blackboard, ^ref, tuple} ->
        if report?,
          do: send(report_to, {:latency, tag, now_ns() - elem(tuple, tuple_size(tuple) - 1)})

        subscriber_loop(ref, report_to, tag, report?)

      {:raw, sent} ->
        send(report_to, {:latency, :send, now_ns() - sent})
        subscriber_loop(ref, report_to, tag, report?)

      :stop ->
        :ok
    end
  end

  @doc """
  Runs `count` takers of `template` until nothing arrives for `idle_ms`;
  returns the third element of every tuple they took.
  """
  @spec take_all(Blackboard.template(), pos_integer(), pos_integer()) :: [term()]
  def take_all(template, count, idle_ms) do
    1..count
    |> Enum.map(fn _ -> Task.async(fn -> take_loop(template, idle_ms, []) end) end)
    |> Enum.flat_map(&Task.await(&1, :infinity))
  end

  defp take_loop(template, idle_ms, acc) do
    case Blackboard.take(template, idle_ms) do
      {:ok, tuple} -> take_loop(template, idle_ms, [elem(tuple, 2) | acc])
      {:error, :timeout} -> acc
    end
  end

  @doc "Writes `{tag, node(), {node(), i}}` for every i in `range`."
  @spec write(atom(), Range.t()) :: :ok
  def write(tag, range) do
    for i <- range, do: Blackboard.out({tag, node(), {node(), i}})
    :ok
  end
end
