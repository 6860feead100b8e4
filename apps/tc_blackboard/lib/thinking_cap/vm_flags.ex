defmodule ThinkingCap.VMFlags do
  @moduledoc """
  The emulator flags every ThinkingCap node runs with: the release's
  (`rel/vm.args.eex`), `bin/run`'s, the benchmarks' (`mix tc.bench` runs
  itself again with them) and the peers of `ThinkingCap.Testing.Cluster`.

    * `+sbwt none +sbwtdcpu none +sbwtdio none`: the schedulers do not
      busy-wait. The runtime may run them at real-time priority
      (`ThinkingCap.Runtime.Scheduling`), where a spinning scheduler takes
      a core from everything below it.
    * `+MHsbct 8192 +MHlmbcs 32768`: process heaps up to 8 MB live in the
      heap allocator's multiblock carriers (up to 32 MB each), which it
      keeps and reuses. By default a heap above 512 KB gets a carrier of
      its own, mapped for it and unmapped after its next garbage
      collection: each unmap flushes the TLB of every core (an
      inter-processor interrupt) and each new map takes a page fault per
      page. A simulator shard's heap (16 robots' scans a step) is that
      big: at 1,000 robots `perf` put 13 % of the CPU time in `munmap`
      and page faults, and the fleet ran 30 % faster with these flags
      (`mix tc.bench sim`, README).
  """

  @scheduler ~w(+sbwt none +sbwtdcpu none +sbwtdio none)
  @heap ~w(+MHsbct 8192 +MHlmbcs 32768)

  @doc "The flags, as words: `[\"+sbwt\", \"none\", ...]`."
  @spec words() :: [String.t()]
  def words, do: @scheduler ++ @heap

  @doc "The flags as one string, for `ELIXIR_ERL_OPTIONS`."
  @spec string() :: String.t()
  def string, do: Enum.join(words(), " ")

  @doc "The flags as charlists, for `:peer`'s `args`."
  @spec charlists() :: [charlist()]
  def charlists, do: Enum.map(words(), &String.to_charlist/1)

  @doc """
  Whether the running emulator was started with every flag (Linux:
  `/proc/self/cmdline`; elsewhere true: there is nothing to protect).
  """
  @spec set?() :: boolean()
  def set? do
    case File.read("/proc/#{System.pid()}/cmdline") do
      {:ok, cmdline} ->
        words()
        |> Enum.chunk_every(2)
        |> Enum.all?(fn ["+" <> flag, value] -> cmdline =~ "-#{flag}" <> <<0>> <> value end)

      {:error, _} ->
        true
    end
  end
end
