defmodule ThinkingCap.Runtime.TupleLogger do
  @moduledoc """
  Logs a robot's blackboard to a text file, when nothing else runs: a
  background module (ADF `activity: :background`).

      logger: [module: ThinkingCap.Runtime.TupleLogger, activity: :background,
               params: [path: "tmp/tc.log"]]

  It subscribes to every tuple of its robot (`{_, robot, _}`) and writes
  each as a line: the time in milliseconds since the epoch, then the tuple
  as `inspect/2` prints it, cut at `max_line` bytes. Lines are kept in
  memory until the background runs (at low process priority); at most
  `max_buffer` bytes wait, and what comes beyond is counted and the count
  logged. When the file passes `max_bytes` it is renamed to `path.1`
  (the one before dropped) and a new one started: at most twice
  `max_bytes` on disk. A path that cannot be written is logged once,
  naming it; the module runs on and drops lines.
  """

  use ThinkingCap.Module
  require Logger

  @params [
    path: {:string, default: "tmp/tc.log", read_only: true, doc: "the log file"},
    max_bytes:
      {{:int_range, 1024, 10_000_000_000},
       default: 10_000_000, doc: "bytes before the file is rotated to path.1"},
    max_line: {{:int_range, 80, 1_000_000}, default: 2_000, doc: "bytes of a line at most"},
    max_buffer:
      {{:int_range, 1024, 1_000_000_000},
       default: 4_000_000, doc: "bytes waiting to be written at most; beyond: dropped"}
  ]
  @defaults ThinkingCap.Config.Schema.defaults(@params)

  @doc "The params this module takes (`c:ThinkingCap.Module.params/0`)."
  @impl true
  @spec params() :: keyword()
  def params, do: @params

  @impl true
  def init(params, context) do
    params = Keyword.merge(@defaults, Enum.to_list(params || []))

    state = %{
      robot: context.robot,
      params: params,
      buffer: [],
      buffered: 0,
      dropped: 0,
      failed: false
    }

    {[subscribe: {:_, context.robot, :_}], state}
  end

  @impl true
  def handle_tuple(tuple, %{params: p} = state) do
    line = [Integer.to_string(System.os_time(:millisecond)), " ", cut(tuple, p[:max_line]), "\n"]
    size = IO.iodata_length(line)

    if state.buffered + size > p[:max_buffer],
      do: {[], %{state | dropped: state.dropped + 1}},
      else: {[], %{state | buffer: [line | state.buffer], buffered: state.buffered + size}}
  end

  defp cut(tuple, max) do
    text = inspect(tuple, limit: 100, printable_limit: max)
    if byte_size(text) > max, do: [binary_part(text, 0, max), "…"], else: text
  end

  @impl true
  def handle_background(%{buffer: []} = state) do
    # nothing to write: do not spin
    Process.sleep(100)
    {[], state}
  end

  def handle_background(state), do: {[], flush(state)}

  @impl true
  def terminate(_reason, state) do
    _ = flush(state)
    :ok
  end

  defp flush(%{buffer: []} = state), do: state

  defp flush(%{params: p} = state) do
    path = p[:path]
    dropped = if state.dropped > 0, do: [["# #{state.dropped} tuples dropped\n"]], else: []
    lines = Enum.reverse(state.buffer, dropped)

    with :ok <- File.mkdir_p(Path.dirname(path)),
         :ok <- write(path, lines, size(path), p[:max_bytes]) do
      %{state | buffer: [], buffered: 0, dropped: 0}
    else
      {:error, reason} ->
        unless state.failed do
          Logger.warning(
            "#{inspect(state.robot)}: tuple log #{path} not written: #{:file.format_error(reason)}"
          )
        end

        %{state | buffer: [], buffered: 0, failed: true}
    end
  end

  # appends the lines, renaming the file to path.1 whenever it reaches
  # `max` bytes: a file never holds much more than `max`
  defp write(_path, [], _size, _max), do: :ok

  defp write(path, lines, size, max) when size >= max do
    with :ok <- File.rename(path, path <> ".1"), do: write(path, lines, 0, max)
  end

  defp write(path, lines, size, max) do
    {chunk, rest, size} = take(lines, size, max, [])

    with :ok <- File.write(path, Enum.reverse(chunk), [:append]),
         do: write(path, rest, size, max)
  end

  # the lines that fit before `max` (at least one)
  defp take([line | rest], size, max, acc) when acc == [] or size < max,
    do: take(rest, size + IO.iodata_length(line), max, [line | acc])

  defp take(rest, size, _max, acc), do: {acc, rest, size}

  defp size(path) do
    case File.stat(path) do
      {:ok, %File.Stat{size: size}} -> size
      _ -> 0
    end
  end
end
