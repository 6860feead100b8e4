defmodule ThinkingCap.Bench.ProcStat do
  @moduledoc """
  Figures benchmarks read from Linux's `/proc`: the clock-tick unit of its
  CPU times, and the time the hypervisor took from this machine's CPUs.
  """

  @doc "Clock ticks per second, the unit of `/proc`'s CPU times (`getconf CLK_TCK`; 100 where unknown)."
  @spec clock_ticks() :: pos_integer()
  def clock_ticks do
    case System.cmd("getconf", ["CLK_TCK"], stderr_to_stdout: true) do
      {out, 0} -> out |> String.trim() |> String.to_integer()
      _ -> 100
    end
  end

  @doc """
  CPU time, in ms, that the hypervisor gave to others while this machine's
  CPUs were ready to run (the steal column of `/proc/stat`, all CPUs), since
  boot; 0 where unknown. No guest program can be on time while its CPU is
  taken away, so a benchmark reports the steal over its window.
  """
  @spec steal_ms() :: non_neg_integer()
  def steal_ms do
    with {:ok, stat} <- File.read("/proc/stat"),
         ["cpu" | fields] <- stat |> String.split("\n", parts: 2) |> hd() |> String.split(),
         steal when is_binary(steal) <- Enum.at(fields, 7) do
      div(String.to_integer(steal) * 1000, clock_ticks())
    else
      _ -> 0
    end
  end
end
