defmodule Mix.Tasks.Tc.Movingai do
  @shortdoc "Runs A* on a Moving AI benchmark: mix tc.movingai MAP SCEN"
  @moduledoc """
  Runs `ThinkingCap.Navigation.AStar` on every problem of a Moving AI
  scenario file and checks its costs against the file's optimal lengths.

      mix tc.movingai test/data/movingai/arena.map test/data/movingai/arena.map.scen
      mix tc.movingai --jobs 2 MAP SCEN

  Paths are relative to the current directory. It prints figures per band
  of buckets (each bucket on its own when there are at most 20), then one
  summary line

      movingai: problems=N optimal=N mean_us=U

  where `optimal` counts the costs within 1e-4 of the file's optimal
  length and `mean_us` is the mean wall time of one plan in microseconds.
  `--jobs N` (default 1) solves N problems at once (each still timed on
  its own). The task fails when a problem is not solved optimally.
  """
  use Mix.Task

  alias ThinkingCap.Navigation.MovingAI

  @impl true
  def run(args) do
    {opts, paths} = OptionParser.parse!(args, strict: [jobs: :integer])

    [map_path, scen_path] =
      with [_, _] <- paths, do: paths, else: (_ -> Mix.raise("usage: mix tc.movingai MAP SCEN"))

    grid = ok!(MovingAI.load_map(map_path))
    problems = ok!(MovingAI.load_scenarios(scen_path))

    for %{width: w, height: h} = p <- problems, {w, h} != {grid.width, grid.height} do
      Mix.raise(
        "#{scen_path}: problem #{inspect(p.start_xy)} is for a #{w}×#{h} map, " <>
          "#{map_path} is #{grid.width}×#{grid.height}"
      )
    end

    jobs = opts[:jobs] || 1
    solutions = MovingAI.solve(grid, problems, jobs: jobs)

    IO.puts(
      "#{Path.basename(map_path)}: #{grid.width}×#{grid.height}, #{length(problems)} problems, " <>
        "#{jobs} job(s)"
    )

    print_buckets(solutions)
    n = length(solutions)
    optimal = Enum.count(solutions, & &1.optimal)
    mean_us = if n == 0, do: 0, else: round(Enum.sum(Enum.map(solutions, & &1.us)) / n)
    IO.puts("movingai: problems=#{n} optimal=#{optimal} mean_us=#{mean_us}")

    if optimal < n, do: Mix.raise("#{n - optimal} problem(s) not solved optimally")
  end

  defp ok!({:ok, value}), do: value
  defp ok!({:error, message}), do: Mix.raise(message)

  defp print_buckets([]), do: :ok

  defp print_buckets(solutions) do
    top = solutions |> Enum.map(& &1.problem.bucket) |> Enum.max()
    band = if top < 20, do: 1, else: div(top + 10, 10)

    solutions
    |> Enum.group_by(&div(&1.problem.bucket, band))
    |> Enum.sort()
    |> Enum.each(fn {b, group} ->
      n = length(group)
      last = min(b * band + band - 1, top)
      label = if band == 1, do: "bucket #{b}", else: "buckets #{b * band}-#{last}"

      IO.puts(
        "  #{String.pad_trailing(label, 16)} #{n} problems, " <>
          "#{Enum.count(group, & &1.optimal)} optimal, " <>
          "mean #{round(mean(group, & &1.us))} us, " <>
          "mean #{round(mean(group, & &1.expanded))} expanded"
      )
    end)
  end

  defp mean(list, f), do: Enum.sum(Enum.map(list, f)) / length(list)
end
