defmodule ThinkingCap.Cycle.Stats do
  @moduledoc """
  Running timing statistics of one periodic activity: the figures of the
  ThinkingCap-II paper's timing tables. Release jitter (how late each
  release left the timing worker), timer lateness (how late the worker's
  thread woke after its timer, what `cyclictest` measures; with the
  worker's early wake-up the release itself is later only when this
  exceeds it), response time (release to result),
  cycle time (between consecutive releases), "CPU time" (`cpu_us`: the
  time the module's callback took, from its start to its result, on the
  wall clock: the module's own computation, and any time its process
  waited for a scheduler meanwhile), with mean, standard deviation,
  minimum, maximum and a log2 histogram in microseconds; plus counts of
  cycles, deadline misses (fallbacks applied), late results and releases
  skipped because the worker itself was late.
  """

  defstruct cycles: 0,
            fallbacks: 0,
            late: 0,
            skipped: 0,
            last_scheduled: nil,
            period_ns: nil,
            jitter: nil,
            timer: nil,
            response: nil,
            cycle_time: nil,
            cpu: nil

  @typedoc "Welford accumulator with min, max and histogram (µs buckets: <1, <2, <4, ...)."
  @type series :: %{
          n: non_neg_integer(),
          mean: float(),
          m2: float(),
          min: float(),
          max: float(),
          hist: %{non_neg_integer() => pos_integer()}
        }

  @type t :: %__MODULE__{}

  @doc "Empty statistics for an activity with period `period_ns`."
  @spec new(pos_integer()) :: t()
  def new(period_ns),
    do: %__MODULE__{
      period_ns: period_ns,
      jitter: series(),
      timer: series(),
      cpu: series(),
      response: series(),
      cycle_time: series()
    }

  @doc "Records a release scheduled at `scheduled` that left the worker at `released` (ns)."
  @spec release(t(), integer(), integer()) :: t()
  def release(%__MODULE__{} = s, scheduled, released) do
    {cycle_time, skipped} =
      case s.last_scheduled do
        nil -> {nil, 0}
        last -> {scheduled - last, max(div(scheduled - last, s.period_ns) - 1, 0)}
      end

    s = %{s | cycles: s.cycles + 1, skipped: s.skipped + skipped, last_scheduled: scheduled}
    s = %{s | jitter: add(s.jitter, (released - scheduled) / 1000)}
    if cycle_time, do: %{s | cycle_time: add(s.cycle_time, cycle_time / 1000)}, else: s
  end

  @doc "Records how late the worker's thread woke after its timer for a release (ns)."
  @spec timer(t(), non_neg_integer()) :: t()
  def timer(%__MODULE__{} = s, late_ns), do: %{s | timer: add(s.timer, late_ns / 1000)}

  @doc "Records what the worker applied: `:fresh` (with its response time), `:fallback` or `:late`."
  @spec applied(t(), :fresh | :fallback | :late, integer()) :: t()
  def applied(s, :fresh, response_ns), do: %{s | response: add(s.response, response_ns / 1000)}
  def applied(s, :fallback, _response_ns), do: %{s | fallbacks: s.fallbacks + 1}
  def applied(s, :late, _response_ns), do: %{s | late: s.late + 1}

  @doc "Records the time the module's callback took to compute one cycle's result (ns, wall clock)."
  @spec cpu(t(), integer()) :: t()
  def cpu(s, ns), do: %{s | cpu: add(s.cpu, ns / 1000)}

  @doc "A plain map of the figures (times in µs)."
  @spec summary(t()) :: map()
  def summary(%__MODULE__{} = s) do
    %{
      cycles: s.cycles,
      fallbacks: s.fallbacks,
      late: s.late,
      skipped: s.skipped,
      period_us: s.period_ns / 1000,
      jitter_us: figures(s.jitter),
      timer_late_us: figures(s.timer),
      response_us: figures(s.response),
      cycle_us: figures(s.cycle_time),
      cpu_us: figures(s.cpu)
    }
  end

  defp series, do: %{n: 0, mean: 0.0, m2: 0.0, min: nil, max: nil, hist: %{}}

  defp add(%{n: n, mean: mean, m2: m2} = st, x) do
    n = n + 1
    delta = x - mean
    mean = mean + delta / n
    bucket = if x < 1, do: 0, else: trunc(:math.log2(x)) + 1

    %{
      st
      | n: n,
        mean: mean,
        m2: m2 + delta * (x - mean),
        min: if(st.min, do: min(st.min, x), else: x),
        max: if(st.max, do: max(st.max, x), else: x),
        hist: Map.update(st.hist, bucket, 1, &(&1 + 1))
    }
  end

  defp figures(%{n: 0}), do: %{n: 0}

  defp figures(%{n: n, mean: mean, m2: m2} = st) do
    %{n: n, mean: mean, std: :math.sqrt(m2 / n), min: st.min, max: st.max, hist: st.hist}
  end
end
