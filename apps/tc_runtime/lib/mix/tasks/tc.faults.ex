defmodule Mix.Tasks.Tc.Faults do
  @shortdoc "Runs the fault-injection suite (test/faults) and prints its summary line"
  @moduledoc """
  Runs the cross-app fault-injection suite in `test/faults/` (tests
  tagged `:faults`) with the whole umbrella started, then prints one
  summary line:

      faults: injected=… survived=… tuples_lost=… max_uncommanded_ms=…

  *injected* counts the faults the tests injected, *survived* those after
  which everything the test checks held; *tuples_lost* adds up blackboard
  tuples that should have survived a fault and did not; *max_uncommanded_ms*
  is the longest time a robot's periodic activity ran on a fresh command
  without the next command (fresh or fallback) being applied.

      MIX_ENV=test mix tc.faults [--seed N] [--trace] [FILE...]

  `bin/test` runs it after the apps' tests. It exits non-zero when a test
  fails.
  """
  use Mix.Task

  @impl true
  def run(args) do
    {opts, files, _} = OptionParser.parse(args, strict: [seed: :integer, trace: :boolean])

    unless Mix.env() == :test,
      do: Mix.raise("mix tc.faults needs the test environment: MIX_ENV=test mix tc.faults")

    Mix.Task.run("app.start")
    root = File.cwd!()

    ExUnit.start(
      autorun: false,
      timeout: 180_000,
      seed: opts[:seed] || :rand.uniform(999_999),
      trace: opts[:trace] || false,
      include: [:faults]
    )

    for support <- Path.wildcard(Path.join(root, "test/faults/support/*.ex")),
        do: Code.require_file(support)

    files =
      case files do
        [] -> Path.wildcard(Path.join(root, "test/faults/**/*_test.exs"))
        given -> Enum.map(given, &Path.expand/1)
      end

    tally = ThinkingCap.FaultSuite.Tally
    tally.start()
    Kernel.ParallelCompiler.require(files)
    %{failures: failures} = ExUnit.run()
    IO.puts(tally.summary_line())

    if failures > 0, do: exit({:shutdown, 1})
  end
end
