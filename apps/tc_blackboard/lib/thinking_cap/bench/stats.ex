defmodule ThinkingCap.Bench.Stats do
  @moduledoc """
  Figures for benchmarks (`mix tc.bench NAME`): percentiles, mean and
  standard deviation of samples, and the one summary line every benchmark
  ends with (`NAME: key=value ...`).
  """

  @typedoc "Summary of a list of numeric samples."
  @type summary :: %{
          n: non_neg_integer(),
          mean: float(),
          std: float(),
          min: number(),
          p50: number(),
          p99: number(),
          max: number()
        }

  @doc "Summarises `samples` (any non-empty list of numbers)."
  @spec summarize([number()]) :: summary()
  def summarize([_ | _] = samples) do
    sorted = Enum.sort(samples)
    n = length(sorted)
    mean = Enum.sum(sorted) / n
    variance = Enum.reduce(sorted, 0.0, fn x, acc -> acc + (x - mean) * (x - mean) end) / n
    tuple = List.to_tuple(sorted)

    %{
      n: n,
      mean: mean,
      std: :math.sqrt(variance),
      min: elem(tuple, 0),
      p50: percentile(tuple, n, 50),
      p99: percentile(tuple, n, 99),
      max: elem(tuple, n - 1)
    }
  end

  # nearest-rank percentile over a sorted tuple
  defp percentile(sorted, n, p), do: elem(sorted, max(ceil(p / 100 * n) - 1, 0))

  @doc "Prints one row of a latency table (values in the samples' unit)."
  @spec print_row(String.t(), summary()) :: :ok
  def print_row(label, s) do
    IO.puts(
      String.pad_trailing(label, 34) <>
        Enum.map_join(
          [s.p50, s.p99, s.mean, s.std, s.max],
          "",
          &String.pad_leading(format(&1), 10)
        )
    )
  end

  @doc "Prints the header matching `print_row/2`."
  @spec print_header(String.t()) :: :ok
  def print_header(unit) do
    IO.puts(
      String.pad_trailing("(#{unit})", 34) <>
        Enum.map_join(~w(p50 p99 mean std max), "", &String.pad_leading(&1, 10))
    )
  end

  @doc "Prints the summary line: `name: k1=v1 k2=v2 ...`."
  @spec print_summary(String.t(), [{atom() | String.t(), term()}]) :: :ok
  def print_summary(name, pairs) do
    IO.puts(name <> ": " <> Enum.map_join(pairs, " ", fn {k, v} -> "#{k}=#{format(v)}" end))
  end

  @doc "Formats a figure for the tables and the summary line."
  @spec format(term()) :: String.t()
  def format(v) when is_float(v) and v >= 100 and v == round(v),
    do: :erlang.float_to_binary(v, decimals: 0)

  # a value near a round number keeps the digits that separate them (99.88, not 100)
  def format(v) when is_float(v) and v >= 10, do: v |> Float.round(2) |> Float.to_string()
  def format(v) when is_float(v), do: :erlang.float_to_binary(v, decimals: 2)
  def format(v), do: to_string(v)
end
