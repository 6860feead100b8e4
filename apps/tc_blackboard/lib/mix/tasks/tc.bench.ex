defmodule Mix.Tasks.Tc.Bench do
  @shortdoc "Runs a benchmark: mix tc.bench NAME"
  @moduledoc """
  Runs the benchmark `bench/NAME_bench.exs` of the umbrella and prints its
  figures, ending with one summary line `NAME: key=value ...`.

      mix tc.bench blackboard

  A benchmark file defines `ThinkingCap.Bench.<Name>` with `run(args)`.
  Benchmarks start what they compare against themselves.
  """
  use Mix.Task

  @impl true
  def run([name | args]) do
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

  def run([]), do: Mix.raise("usage: mix tc.bench NAME")

  # the umbrella root when run from there or from an app
  defp root do
    cwd = File.cwd!()
    if File.dir?(Path.join(cwd, "apps")), do: cwd, else: Path.expand("../..", cwd)
  end
end
