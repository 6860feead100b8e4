defmodule ThinkingCap.Runtime.Scheduling do
  @moduledoc """
  How the OS schedules the BEAM's own threads, so that the control
  activity gets the CPU under load.

  The timing worker is a separate thread at `SCHED_FIFO` priority 80: its
  releases and fallbacks never wait for the BEAM. But a fresh command has
  to be computed by the BEAM, whose scheduler threads are ordinary threads
  that compete with every other process on the machine. So the runtime
  raises the BEAM's normal scheduler threads and its I/O poller (through
  which the worker's frames arrive) to nice −10: under contention the
  kernel's fair scheduler then gives them about nine times the share of a
  nice-0 process.

  Deliberately **not** a real-time policy: BEAM schedulers spin while
  looking for work, and a busy BEAM at `SCHED_FIFO` would starve the rest
  of the machine, the timing worker's peers and the serial drivers
  included. Dirty schedulers (long NIFs, file I/O) stay at normal priority.

  Applied at start when the `:tc_runtime, :beam_nice` application setting
  is an integer (default −10; `nil` leaves the BEAM as it is). Lowering a
  nice value needs root or `CAP_SYS_NICE`; without it the runtime logs
  that and carries on.
  """
  require Logger

  @doc """
  Sets the nice value of the BEAM's normal scheduler and poller threads.
  Returns the thread ids changed.
  """
  @spec raise_priority(integer()) :: {:ok, [String.t()]} | {:error, String.t()}
  def raise_priority(nice) when is_integer(nice) do
    case threads(~r/^\d+_(scheduler|poller)$/) do
      [] ->
        {:error, "no scheduler threads found under /proc/#{System.pid()}/task"}

      tids ->
        case System.cmd("renice", ["-n", "#{nice}", "-p" | tids], stderr_to_stdout: true) do
          {_, 0} -> {:ok, tids}
          {output, _} -> {:error, String.trim(output)}
        end
    end
  rescue
    e in ErlangError -> {:error, "renice unavailable: #{Exception.message(e)}"}
  end

  @doc "The nice value of each of the BEAM's scheduler and poller threads, by thread name."
  @spec priorities() :: %{String.t() => integer()}
  def priorities do
    for tid <- threads(~r/^\d+_(scheduler|poller)$/), into: %{} do
      stat = File.read!("/proc/#{System.pid()}/task/#{tid}/stat")
      # fields after the ")" that closes the thread name; nice is the 19th field overall
      [_, rest] = String.split(stat, ") ", parts: 2)
      nice = rest |> String.split(" ") |> Enum.at(16) |> String.to_integer()
      {comm(tid), nice}
    end
  end

  @doc false
  # Applies the :beam_nice setting (called when the runtime starts).
  @spec apply_config() :: :ok
  def apply_config do
    case Application.get_env(:tc_runtime, :beam_nice, -10) do
      nil ->
        :ok

      nice ->
        case raise_priority(nice) do
          {:ok, tids} ->
            Logger.info(
              "BEAM scheduler and poller threads at nice #{nice} (#{length(tids)} threads)"
            )

          {:error, reason} ->
            Logger.warning(
              "could not set the BEAM's scheduler threads to nice #{nice}: #{reason}"
            )
        end
    end
  end

  defp threads(pattern) do
    for dir <- Path.wildcard("/proc/#{System.pid()}/task/*"),
        tid = Path.basename(dir),
        Regex.match?(pattern, comm(tid)),
        do: tid
  end

  defp comm(tid) do
    case File.read("/proc/#{System.pid()}/task/#{tid}/comm") do
      {:ok, name} -> String.trim(name)
      {:error, _} -> ""
    end
  end
end
