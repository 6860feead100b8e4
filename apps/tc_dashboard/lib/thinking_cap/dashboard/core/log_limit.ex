defmodule ThinkingCap.Dashboard.Core.LogLimit do
  @moduledoc false
  # yaws logs one line for each connection it closes at its connection
  # cap: a flood of 20,000 connections would write 20,000 lines. This
  # logger filter lets one such line through a minute, with the count of
  # those dropped since.

  @filter :tc_dashboard_yaws_flood
  @every_s 60
  @flood ~c"Max connections reached"

  @doc "Installs the filter (once per node)."
  @spec install() :: :ok
  def install do
    counters = :atomics.new(2, signed: true)
    :atomics.put(counters, 1, System.monotonic_time(:second) - @every_s)
    _ = :logger.remove_primary_filter(@filter)
    :ok = :logger.add_primary_filter(@filter, {&__MODULE__.filter/2, counters})
  end

  @doc false
  # error_logger:format/2 (which yaws uses) logs a report holding its
  # format and arguments
  def filter(%{msg: {:report, %{format: format, args: args}}} = event, counters)
      when is_list(format) do
    if List.starts_with?(format, @flood), do: limit(event, format, args, counters), else: :ignore
  end

  def filter(%{msg: {format, args}} = event, counters) when is_list(format) do
    if List.starts_with?(format, @flood), do: limit(event, format, args, counters), else: :ignore
  end

  def filter(_event, _counters), do: :ignore

  defp limit(event, format, args, counters) do
    now = System.monotonic_time(:second)
    last = :atomics.get(counters, 1)

    if now - last >= @every_s and :atomics.compare_exchange(counters, 1, last, now) == :ok do
      case :atomics.exchange(counters, 2, 0) do
        0 ->
          event

        dropped ->
          %{
            event
            | msg:
                {format ++ ~c"(and ~b more such connections closed since the last report)~n",
                 args ++ [dropped]}
          }
      end
    else
      :atomics.add(counters, 2, 1)
      :stop
    end
  end
end
