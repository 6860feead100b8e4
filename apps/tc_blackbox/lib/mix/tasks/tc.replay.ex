defmodule Mix.Tasks.Tc.Replay do
  @shortdoc "Replays a recording: mix tc.replay FILE [--speed X | --step]"
  @moduledoc """
  Feeds a recording into the blackboard on a clock of its own and runs
  the recorded modules again on what they received, each compared with
  what it did (`ThinkingCap.BlackBox.Replay`):

      mix tc.replay FILE... [--speed X | --step] [--robot ID]
                    [--only NAMES | --exclude NAMES]

  `FILE...` is one recording (`bin/run --record DIR`, an ADF's
  `record:` section, or a black box's dump), in one file or several (a
  recording rotates). The modules run again are every module the
  recording traced, or `--only` those named, or all but those named in
  `--exclude` (names comma-separated, or the option given again); their
  recorded outputs are left out of the feed, and what they write now is
  written in their place. A robot's driver is never run again: what it
  wrote is what the robot sensed.

    * `--speed X` - recorded seconds per second (default 1: real time;
      10 ten times faster; `max` as fast as it goes);
    * `--step` - one tuple or callback at a time: Enter for the next, a
      number N for the next N, `q` to stop;
    * `--robot ID` - the robot whose recording it is, among files of
      several.

  It prints what the recording holds, then each module's replay (its
  callbacks, outputs, how many equal, the first difference, or why it
  stopped) and a summary line:

      replay: fed=4512 left_out=1342 outputs=2310 equal=2310 replay_equal_pct=100.0

  Tuples and modules' code are read from this checkout: a module's new
  version replays in the recorded one's place.
  """
  use Mix.Task

  alias ThinkingCap.BlackBox.Replay

  @switches [speed: :string, step: :boolean, robot: :string, only: :keep, exclude: :keep]

  @impl true
  def run(argv) do
    {opts, files, invalid} = OptionParser.parse(argv, strict: @switches)

    if invalid != [],
      do: Mix.raise("tc.replay: unknown or malformed option #{elem(hd(invalid), 0)}; #{usage()}")

    if files == [], do: Mix.raise("tc.replay: no recording given; #{usage()}")
    speed = speed(opts[:speed])

    if opts[:step] && opts[:speed],
      do: Mix.raise("tc.replay: give --speed or --step, not both")

    Mix.Task.run("app.start")

    rec =
      case Replay.open(files, robot: opts[:robot]) do
        {:ok, rec} -> rec
        {:error, message} -> Mix.raise("tc.replay: #{message}")
      end

    describe(rec, files)

    run_opts =
      [speed: speed, step: if(opts[:step], do: &step/1)]
      |> Keyword.merge(modules(rec, opts))
      |> Enum.reject(fn {_k, v} -> v == nil end)

    case Replay.run(rec, run_opts) do
      {:ok, result} -> summary(result)
      {:error, message} -> Mix.raise("tc.replay: #{message}")
    end
  end

  defp usage,
    do:
      "usage: mix tc.replay FILE... [--speed X | --step] [--robot ID] " <>
        "[--only NAMES | --exclude NAMES]"

  defp speed(nil), do: 1.0
  defp speed("max"), do: :max

  defp speed(text) do
    case Float.parse(text) do
      {x, ""} when x > 0 ->
        x

      _ ->
        Mix.raise("tc.replay: --speed: expected a positive number or max, got #{inspect(text)}")
    end
  end

  # names given on the command line, as the recording knows them
  defp modules(rec, opts) do
    known = Map.new(Replay.modules(rec), &{Atom.to_string(&1.name), &1.name})

    names = fn key ->
      for value <- Keyword.get_values(opts, key),
          text <- String.split(value, ",", trim: true),
          do:
            Map.get(known, String.trim(text)) ||
              Mix.raise(
                "tc.replay: --#{key}: no module #{text} in the recording " <>
                  "(traced: #{known |> Map.keys() |> Enum.sort() |> Enum.join(", ")})"
              )
    end

    case {names.(:only), names.(:exclude)} do
      {[], []} -> []
      {only, []} -> [only: only]
      {[], exclude} -> [exclude: exclude]
      _ -> Mix.raise("tc.replay: give --only or --exclude, not both")
    end
  end

  defp describe(rec, files) do
    IO.puts("replay: #{Enum.join(files, ", ")}: robot #{Replay.robot(rec)}")

    for m <- Replay.modules(rec) do
      start = if m.from_start, do: "", else: " (recorded after it started: not replayable)"

      IO.puts(
        "  #{m.name}: #{inspect(m.module)}, #{m.activity}, #{m.callbacks} callbacks#{start}"
      )
    end
  end

  # Enter: the next; a number: that many; q: stop
  defp step(%{time: time, text: text}) do
    prompt = "t=#{:erlang.float_to_binary(time, decimals: 3)} s #{text} > "

    case IO.gets(prompt) do
      :eof ->
        :stop

      {:error, _} ->
        :stop

      line ->
        case String.trim(line) do
          "q" ->
            :stop

          "" ->
            :continue

          n ->
            case Integer.parse(n) do
              {n, ""} when n > 0 -> {:skip, n - 1}
              _ -> :continue
            end
        end
    end
  end

  defp summary(%{fed: fed, left_out: left_out, modules: reports}) do
    for {name, r} <- Enum.sort(reports) do
      IO.puts(
        "#{name}: #{r.callbacks} callbacks, #{r.equal} of #{r.outputs} outputs equal" <>
          if(r.measured > 0, do: " (#{r.measured} but for measurements)", else: "") <>
          if(r.stopped, do: "; stopped: #{r.stopped}", else: "")
      )

      for d <- Enum.take(r.first_differences, 1) do
        IO.puts("  first difference, callback #{d.callback} (#{inspect(d.input)}):")
        IO.puts("    recorded: #{inspect(d.recorded, limit: 8, printable_limit: 120)}")
        IO.puts("    replayed: #{inspect(d.replayed, limit: 8, printable_limit: 120)}")
      end
    end

    outputs = reports |> Map.values() |> Enum.map(& &1.outputs) |> Enum.sum()
    equal = reports |> Map.values() |> Enum.map(& &1.equal) |> Enum.sum()
    pct = :erlang.float_to_binary(Replay.equal_pct(reports), decimals: 1)

    IO.puts(
      "replay: fed=#{fed} left_out=#{left_out} outputs=#{outputs} equal=#{equal} " <>
        "replay_equal_pct=#{pct}"
    )
  end
end
