defmodule ThinkingCap.Bench.Cyclictest do
  @moduledoc """
  `cyclictest` (Debian rt-tests), the physical reference for wake-up
  latency: a thread on each CPU at `SCHED_FIFO` priority 80 sleeps for a
  period and measures how late it wakes. On a virtual machine whose CPUs
  stall now and then, it shows what the machine itself does to every
  real-time thread, the robot's included. The timing benchmark runs it
  beside the control cycle; the fault suite beside its faults, to tell the
  framework's delays from the machine's.
  """

  @typedoc "A running cyclictest, or nil when it is not installed."
  @type t :: port() | nil

  @type result :: %{
          p50: non_neg_integer() | nil,
          p99: non_neg_integer() | nil,
          max: non_neg_integer() | nil,
          over: non_neg_integer() | nil
        }

  @doc """
  Starts cyclictest for `seconds` with a period of `interval_us`
  microseconds, and returns once it measures: its thread on each CPU
  running and two periods gone. Returns nil when the executable is
  missing.

  Returning at once was not enough: a fault window of a few milliseconds
  (a node killed, the wheels' stop seen) could end before cyclictest's
  threads had woken once. It then reported a worst latency of 0, and a
  fault test took that for a machine that had not stalled.
  """
  @spec start(pos_integer(), pos_integer()) :: t()
  def start(seconds, interval_us \\ 10_000) do
    case System.find_executable("cyclictest") do
      nil ->
        nil

      exe ->
        # -S: a thread on each CPU (a CPU of a virtual machine can stall
        # alone); -h: a histogram in microseconds
        args = ["-m", "-S", "-p80", "-i#{interval_us}", "-D", "#{seconds}s", "-q", "-h", "20000"]

        port = Port.open({:spawn_executable, exe}, [:binary, :exit_status, args: args])
        await_threads(port, System.monotonic_time(:millisecond) + 2_000)
        Process.sleep(max(1, div(2 * interval_us, 1000)))
        port
    end
  end

  # cyclictest's main thread and one measuring thread a CPU (up to a
  # deadline: without /proc, or if it failed, the caller reads what it
  # printed)
  defp await_threads(port, deadline) do
    with {:os_pid, pid} <- Port.info(port, :os_pid),
         {:ok, tasks} <- File.ls("/proc/#{pid}/task"),
         true <- length(tasks) <= :erlang.system_info(:logical_processors_online),
         true <- System.monotonic_time(:millisecond) < deadline do
      Process.sleep(1)
      await_threads(port, deadline)
    else
      _ -> :ok
    end
  end

  @doc """
  Stops cyclictest before its time (SIGINT, on which it prints its
  figures) and returns them as `finish/2` does.
  """
  @spec stop(t(), non_neg_integer()) :: result()
  def stop(probe, over_us \\ 3_000)

  def stop(nil, over_us), do: finish(nil, over_us)

  def stop(port, over_us) do
    case Port.info(port, :os_pid) do
      {:os_pid, pid} -> System.cmd("kill", ["-INT", Integer.to_string(pid)])
      nil -> :ok
    end

    finish(port, over_us)
  end

  @doc """
  Waits for cyclictest to end and returns its wake-up latencies in
  microseconds, over every thread: median, 99th percentile, maximum, and
  how many wake-ups were `over_us` late or more. All nil without it.
  """
  @spec finish(t(), non_neg_integer()) :: result()
  def finish(probe, over_us \\ 3_000)

  def finish(nil, _over_us), do: %{p50: nil, p99: nil, max: nil, over: nil}

  def finish(port, over_us) do
    output = read_port(port, "")

    # one count column per thread (CPU), summed
    histogram =
      for line <- String.split(output, "\n"),
          [us | counts] <- [String.split(line)],
          String.match?(us, ~r/^\d{6}$/),
          count <- [counts |> Enum.map(&String.to_integer/1) |> Enum.sum()],
          count > 0,
          do: {String.to_integer(us), count}

    overflows = output |> header_numbers("Histogram Overflows") |> Enum.sum()
    max = output |> header_numbers("Max Latencies") |> Enum.max(fn -> nil end)
    total = Enum.sum(Enum.map(histogram, &elem(&1, 1))) + overflows

    %{
      p50: percentile(histogram, total, 50),
      p99: percentile(histogram, total, 99),
      max: max,
      over: Enum.sum(for({us, n} <- histogram, us >= over_us, do: n)) + overflows
    }
  end

  # the numbers of a "# Name: n n ..." line of cyclictest's, one per thread
  defp header_numbers(output, name) do
    case Regex.run(~r/^# #{name}:((?: \d+)+)/m, output) do
      [_, numbers] -> numbers |> String.split() |> Enum.map(&String.to_integer/1)
      nil -> []
    end
  end

  defp read_port(port, acc) do
    receive do
      {^port, {:data, data}} -> read_port(port, acc <> data)
      {^port, {:exit_status, _}} -> acc
    after
      120_000 -> acc
    end
  end

  defp percentile(_histogram, 0, _p), do: nil

  defp percentile(histogram, total, p) do
    target = Float.ceil(total * p / 100)

    Enum.reduce_while(histogram, 0, fn {us, count}, seen ->
      if seen + count >= target, do: {:halt, {:found, us}}, else: {:cont, seen + count}
    end)
    |> case do
      {:found, us} -> us
      _beyond_histogram -> nil
    end
  end
end
