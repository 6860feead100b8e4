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
    * `+MMscs 1024`: the allocators take their carriers from one range of
      1 GB of address space reserved at start (pages are taken as they
      are touched), where a freed carrier stays mapped. Without it the
      segment cache unmaps freed carriers after a moment, and memory
      mapped again costs a page fault a page at first touch (about 70 µs
      a fault on the virtual machine of the README's figures): a black
      box recorder fed one robot's tuples took 4,400-5,500 faults a round
      of 1,851 tuples, 250-350 with it. A node's memory at start is
      unchanged (39 MB); 100 recorded robots used about 605 MB of it.
  """

  @scheduler ~w(+sbwt none +sbwtdcpu none +sbwtdio none)
  @heap ~w(+MHsbct 8192 +MHlmbcs 32768)
  @segments ~w(+MMscs 1024)

  @doc "The flags, as words: `[\"+sbwt\", \"none\", ...]`."
  @spec words() :: [String.t()]
  def words, do: @scheduler ++ @heap ++ @segments

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
