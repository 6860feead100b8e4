defmodule ThinkingCap.Cycle.Clock do
  @moduledoc """
  The timing worker's clock, read from the BEAM.

  The worker stamps releases (`scheduled_ns`, `released_ns`) and applied
  commands (`applied_ns`) on the OS's `CLOCK_MONOTONIC`. Erlang's own
  monotonic time has another origin and, with time correction on, may
  run slightly faster or slower. `now_ns/0` reads the OS clock through
  `:os.perf_counter/1` and adds the offset between the two, measured once.
  Where the perf counter is `CLOCK_MONOTONIC` itself (Linux), that offset
  is within a few microseconds of zero.

  So a module can tell how late its `handle_cycle/2` started:
  `Clock.now_ns() - release.scheduled_ns`.
  """

  @key {__MODULE__, :offset}

  @doc "Now, in nanoseconds, on the clock of the timing worker's stamps (`CLOCK_MONOTONIC`)."
  @spec now_ns() :: integer()
  def now_ns, do: :os.perf_counter(:nanosecond) + offset()

  defp offset do
    case :persistent_term.get(@key, nil) do
      nil ->
        offset = measure_offset()
        :persistent_term.put(@key, offset)
        offset

      offset ->
        offset
    end
  end

  # the OS monotonic time ERTS reads, against the perf counter read just
  # before and just after; the tightest of a few tries
  defp measure_offset do
    1..5
    |> Enum.map(fn _ ->
      before = :os.perf_counter(:nanosecond)
      os = os_monotonic_ns()
      later = :os.perf_counter(:nanosecond)
      {later - before, os - div(before + later, 2)}
    end)
    |> Enum.min()
    |> elem(1)
  end

  defp os_monotonic_ns do
    source = :erlang.system_info(:os_monotonic_time_source)

    case Keyword.fetch(source, :time) do
      # (in the native time unit, the documentation says)
      {:ok, time} -> :erlang.convert_time_unit(time, :native, :nanosecond)
      # no OS monotonic clock: the perf counter is the best there is
      :error -> :os.perf_counter(:nanosecond)
    end
  end
end
