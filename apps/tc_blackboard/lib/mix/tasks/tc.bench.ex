defmodule Mix.Tasks.Tc.Bench do
  @shortdoc "Runs a benchmark: mix tc.bench NAME"
  @moduledoc """
  Runs the benchmark `bench/NAME_bench.exs` of the umbrella and prints its
  figures, ending with one summary line `NAME: key=value ...`.

      mix tc.bench blackboard

  A benchmark file defines `ThinkingCap.Bench.<Name>` with `run(args)`.
  Benchmarks start what they compare against themselves.

  Benchmarks measure the VM a robot runs: when this one was started
  without the release's scheduler flags (`+sbwt none +sbwtdcpu none
  +sbwtdio none`, rel/vm.args.eex: the runtime may run the schedulers at
  real-time priority, where they must not busy-wait) or its allocators'
  super carrier (`+MMscs 1024`, which keeps freed memory mapped), the
  task runs itself again in a VM that has them.
  """
  use Mix.Task

  @vm_flags "+sbwt none +sbwtdcpu none +sbwtdio none +MMscs 1024"

  @impl true
  def run([name | args]) do
    # (a VM this task started itself runs the benchmark whatever it finds)
    if release_flags?() or System.get_env("TC_BENCH_VM") == "1",
      do: run_here(name, args),
      else: run_with_vm_flags([name | args])
  end

  def run([]), do: Mix.raise("usage: mix tc.bench NAME")

  defp run_here(name, args) do
    file = Path.join([root(), "bench", "#{name}_bench.exs"])

    unless File.exists?(file) do
      available =
        Path.wildcard(Path.join([root(), "bench", "*_bench.exs"]))
        |> Enum.map(&Path.basename(&1, "_bench.exs"))

      Mix.raise(
        "no benchmark #{inspect(name)}: expected #{file}; available: #{Enum.join(available, ", ")}"
      )
    end

    Mix.Task.run("app.start")

    [{module, _} | _] =
      Code.require_file(file) |> Enum.filter(fn {m, _} -> function_exported?(m, :run, 1) end)

    module.run(args)
  end

  defp release_flags? do
    case File.read("/proc/#{System.pid()}/cmdline") do
      {:ok, cmdline} -> cmdline =~ <<"-sbwt", 0, "none">> and cmdline =~ <<"-MMscs", 0>>
      # not Linux: no real-time scheduling to protect
      {:error, _} -> true
    end
  end

  defp run_with_vm_flags(argv) do
    Mix.shell().info("tc.bench: running in a VM with #{@vm_flags}")
    options = String.trim("#{System.get_env("ELIXIR_ERL_OPTIONS")} #{@vm_flags}")

    {_, status} =
      System.cmd("mix", ["tc.bench" | argv],
        env: [{"ELIXIR_ERL_OPTIONS", options}, {"TC_BENCH_VM", "1"}],
        into: IO.stream(:stdio, :line),
        stderr_to_stdout: true
      )

    if status != 0, do: exit({:shutdown, status})
  end

  # the umbrella root when run from there or from an app
  defp root do
    cwd = File.cwd!()
    if File.dir?(Path.join(cwd, "apps")), do: cwd, else: Path.expand("../..", cwd)
  end
end
