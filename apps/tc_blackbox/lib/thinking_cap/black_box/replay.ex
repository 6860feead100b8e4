defmodule ThinkingCap.BlackBox.Replay do
  @moduledoc """
  Replays a recording (`ThinkingCap.BlackBox.Recorder`): runs the
  recorded modules again on exactly what they received, and feeds what
  the robot sensed into the blackboard on a clock of its own.

      {:ok, rec} = Replay.open("recordings/r1_20250101T120000.000Z.mcap")
      Replay.modules(rec)            # what can be run again
      Replay.compare(rec, :control)  # no blackboard, no clock: a report
      Replay.run(rec, speed: 2.0)    # the blackboard fed, twice as fast

  `mix tc.replay` runs `run/2` from a shell; `ThinkingCap.Testing.Replay`
  runs `compare/3` in a test.

  ## What a recording holds for it

  Each tuple whole (`/etf/ID/TAG`, Erlang's external term format), and
  each module's trace (`/trace/ROBOT/NAME`, `ThinkingCap.Runtime.Trace`):
  per callback, its input (the tuple delivered, by tag and hash; the
  release with its times; the command applied; a live param change) and
  what it returned. A module is run again from its `init/2`, with the
  params and context it was started with, then given each recorded input
  in the order it received them, and each callback's outputs are
  compared with the recorded ones. A module's inputs are its own: it is
  run on what it received, not on what another module run again writes.

  ## What replays identically, and what cannot

  Identical: a module whose outputs depend only on what the framework
  gives it (its params and context, the tuples delivered and their order,
  its releases' times, the commands applied for it, live param changes)
  and on random numbers drawn from a seed among its params, on the same
  code and machine. The controller (`ThinkingCap.Control.Blender`), the
  localizer (`ThinkingCap.Navigation.MCL`: its particles' random numbers
  come from its `seed`) and the planner (`ThinkingCap.Planner.Monitor`:
  its time is its releases') replay so.

  Not identical, and why:

    * a duration measured on the machine (the planner's `planning.us`):
      a module declares these (`c:ThinkingCap.Module.replay/0`); they are
      left out of the comparison and counted apart (`measured`);
    * a module that reads a clock, the blackboard (`rd`, `rdp`), a file
      other than its RDF and WDF (the paths recorded must exist where the
      replay runs), or another process: these inputs are not traced;
    * `handle_info/2` messages are given back as recorded, but pids and
      references in them name processes of the recorded run;
    * a module started before the recording began (a recorder started by
      hand while the robot ran, or by the announcement of a deployment
      across nodes, `ThinkingCap.Runtime.deploy/1`, which starts its
      modules first): its state then is not in the recording. A
      recorder started with the ADF by `ThinkingCap.Runtime.start/1`
      (its `record:` section, `bin/run --record`) is ready before the
      first module starts;
    * a recording that lost tuples (the recorder's subscription dropped
      them, `Recorder.info/1`'s `dropped`) or narrowed them (`templates:`)
      runs a module up to the first input it lacks;
    * a robot's driver (`use ThinkingCap.Robot`) is not traced: its inputs
      are its hardware; its outputs are what the robot sensed, and they
      are fed;
    * floating-point results of other code or another machine (a NIF
      built with other flags) may differ in their last bits.

  A run that cannot go on identically stops that module, saying why, in
  its report (`stopped`).
  """

  alias ThinkingCap.BlackBox.Core.{Comparison, Recording}
  alias ThinkingCap.Blackboard

  @typedoc "A recording opened for a replay."
  @opaque recording :: Recording.t()

  @typedoc """
  One module's replay: the callbacks run, their outputs, how many were
  equal (`measured` of them equal but for declared measurements), the
  differences (`first_differences`: the first ten, each with the
  callback's number and input, the recorded output and the replayed
  one), the module's restarts in the recording, and why it `stopped`
  early (nil when it ran to the end). `identical` when every output was
  equal and it ran to the end.
  """
  @type report :: %{
          name: atom(),
          module: module(),
          callbacks: non_neg_integer(),
          outputs: non_neg_integer(),
          equal: non_neg_integer(),
          measured: non_neg_integer(),
          differences: non_neg_integer(),
          first_differences: [map()],
          restarts: non_neg_integer(),
          stopped: String.t() | nil,
          identical: boolean()
        }

  @typedoc "A module that can be run again: its name, its code, its activity, its callbacks recorded."
  @type module_info :: %{
          name: atom(),
          module: module() | nil,
          activity: atom() | nil,
          callbacks: non_neg_integer(),
          from_start: boolean()
        }

  # tuples not fed: they would start services on this node (an ADF's
  # announcement) or ask for a dump
  @not_fed [:adf, :black_box_request]

  @doc """
  Opens a recording: one MCAP file, or the files of one recording (it
  rotates into several). Option `robot:` (a name) picks one robot's files
  among files of several. Errors name the file and the problem.
  """
  @spec open(Path.t() | [Path.t()], keyword()) :: {:ok, recording()} | {:error, String.t()}
  def open(paths, opts \\ []) do
    robot = opts[:robot] && to_string(opts[:robot])
    Recording.read(List.wrap(paths), robot)
  end

  @doc "The robot the recording is of."
  @spec robot(recording()) :: atom()
  def robot(%Recording{robot: robot}), do: robot

  @doc "The seconds from the recording's first message to its last."
  @spec duration(recording()) :: float()
  def duration(%Recording{first: nil}), do: 0.0
  def duration(%Recording{first: first, last: last}), do: (last - first) / 1.0e9

  @doc "The modules the recording traced, by name."
  @spec modules(recording()) :: [module_info()]
  def modules(%Recording{traces: traces}) do
    for {name, [{_, first, _} | _] = events} <- Enum.sort(traces) do
      init =
        Enum.find_value(events, fn {_, _, {input, _}} -> match?({:init, _}, input) && input end)

      info = if init, do: elem(init, 1), else: %{}

      %{
        name: name,
        module: info[:module],
        activity: info[:activity],
        callbacks: length(events),
        from_start: first == 0
      }
    end
  end

  @doc """
  Runs module `name` (or each of a list of names) again on its recorded
  inputs and compares its outputs, without a blackboard or a clock.

  Options, for one module: `module:` runs that module's code in its
  place (a new version, against what the old one did), `params:` (a
  keyword list) goes over the params it was started with.
  """
  @spec compare(recording(), atom() | [atom()], keyword()) ::
          {:ok, %{atom() => report()}} | {:error, String.t()}
  def compare(%Recording{} = rec, names, opts \\ []) do
    with :ok <- check_compare(opts, List.wrap(names)),
         {:ok, names} <- known(rec, List.wrap(names)) do
      reports =
        Map.new(names, fn name ->
          cmp =
            rec.traces[name]
            |> Enum.map(&instead(&1, opts))
            |> Enum.reduce(Comparison.new(name), &elem(Comparison.step(&2, rec, &1), 0))

          {name, Comparison.report(cmp)}
        end)

      {:ok, reports}
    end
  end

  defp check_compare(opts, names) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "compare options: expected a keyword list, got #{inspect(opts)}"}

      unknown = Enum.find(Keyword.keys(opts), &(&1 not in [:module, :params])) ->
        {:error,
         "compare options: unknown option #{inspect(unknown)} (known: [:module, :params])"}

      opts != [] and length(names) != 1 ->
        {:error, "compare options: module: and params: are for one module at a time"}

      not (opts[:module] == nil or is_atom(opts[:module])) ->
        {:error, "compare options: module: expected a module, got #{inspect(opts[:module])}"}

      not (opts[:params] == nil or Keyword.keyword?(opts[:params])) ->
        {:error,
         "compare options: params: expected a keyword list, got #{inspect(opts[:params])}"}

      true ->
        :ok
    end
  end

  # the recorded start, with another module's code or other params
  defp instead({time, n, {{:init, info}, outputs}}, opts) when opts != [] do
    params =
      case {info.params, opts[:params]} do
        {given, nil} -> given
        {given, more} when is_map(given) -> Map.merge(given, Map.new(more))
        {given, more} -> Keyword.merge(given || [], more)
      end

    {time, n, {{:init, %{info | module: opts[:module] || info.module, params: params}}, outputs}}
  end

  defp instead(traced, _opts), do: traced

  @doc """
  The share of the outputs, in per cent, that replayed equal (100.0
  when there were none).
  """
  @spec equal_pct(%{atom() => report()} | [report()]) :: float()
  def equal_pct(reports) do
    reports = if is_map(reports), do: Map.values(reports), else: reports
    outputs = Enum.sum(Enum.map(reports, & &1.outputs))
    equal = Enum.sum(Enum.map(reports, & &1.equal))
    if outputs == 0, do: 100.0, else: 100.0 * equal / outputs
  end

  @options [:speed, :step, :only, :exclude]

  @doc """
  Feeds the recording into the blackboard on a clock of its own and runs
  modules again on it.

  The modules run again are every traced module, or `only:` those named,
  or all but those named in `exclude:`. Their recorded outputs are left
  out of the feed; what they write this time is written to the
  blackboard instead, at the time the recorded callback ran, and
  compared. Everything else is fed as recorded (what the robot sensed,
  the other modules' outputs), latest-value by `ThinkingCap.Tuples.key/1`,
  but an ADF's announcement (`:adf`) and a dump request, which would
  start things on this node.

  Options, checked before anything runs:

    * `speed:` - recorded seconds per second (default 1.0, real time;
      `:max` as fast as it goes);
    * `step:` - a function called before each tuple fed and each
      callback run, with `%{time: seconds_since_start, text: description}`;
      it returns `:continue`, `{:skip, n}` (this one and the `n` after it
      go without asking) or `:stop`. The clock then waits for it.

  Returns the count of tuples fed and left out, and each module's report.
  """
  @spec run(recording(), keyword()) ::
          {:ok,
           %{fed: non_neg_integer(), left_out: non_neg_integer(), modules: %{atom() => report()}}}
          | {:error, String.t()}
  def run(%Recording{} = rec, opts \\ []) do
    with :ok <- check(opts),
         {:ok, names} <- rerun_names(rec, opts) do
      left_out = attribute(rec, names)
      items = items(rec, names, left_out)
      start = %{wall: System.monotonic_time(:millisecond), first: rec.first || 0}
      speed = Keyword.get(opts, :speed, 1.0)
      cmps = Map.new(names, &{&1, Comparison.new(&1)})
      acc = %{cmps: cmps, fed: 0, skip: 0}
      acc = Enum.reduce_while(items, acc, &item(&1, &2, rec, start, speed, opts[:step]))

      {:ok,
       %{
         fed: acc.fed,
         left_out: MapSet.size(left_out),
         modules: Map.new(acc.cmps, fn {name, cmp} -> {name, Comparison.report(cmp)} end)
       }}
    end
  end

  defp check(opts) when is_list(opts) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "replay options: expected a keyword list, got #{inspect(opts)}"}

      unknown = Enum.find(Keyword.keys(opts), &(&1 not in @options)) ->
        {:error,
         "replay options: unknown option #{inspect(unknown)} (known: #{inspect(@options)})"}

      not speed?(Keyword.get(opts, :speed, 1.0)) ->
        {:error,
         "replay options: speed: expected a positive number or :max, got #{inspect(opts[:speed])}"}

      not (opts[:step] == nil or is_function(opts[:step], 1)) ->
        {:error, "replay options: step: expected a function of one argument"}

      opts[:only] != nil and opts[:exclude] != nil ->
        {:error, "replay options: give only: or exclude:, not both"}

      true ->
        :ok
    end
  end

  defp check(opts), do: {:error, "replay options: expected a keyword list, got #{inspect(opts)}"}

  defp speed?(:max), do: true
  defp speed?(x), do: is_number(x) and x > 0

  defp rerun_names(rec, opts) do
    all = rec.traces |> Map.keys() |> Enum.sort()

    cond do
      only = opts[:only] ->
        known(rec, List.wrap(only))

      exclude = opts[:exclude] ->
        with {:ok, ex} <- known(rec, List.wrap(exclude)), do: {:ok, all -- ex}

      true ->
        {:ok, all}
    end
  end

  defp known(rec, names) do
    all = rec.traces |> Map.keys() |> Enum.sort()

    case Enum.reject(names, &(&1 in all)) do
      [] ->
        {:ok, names}

      unknown ->
        {:error,
         "no trace of #{Enum.map_join(unknown, ", ", &inspect/1)} in the recording " <>
           "(traced: #{if all == [], do: "none", else: Enum.map_join(all, ", ", &inspect/1)})"}
    end
  end

  # the positions of the recorded tuples the modules run again wrote (a
  # tuple written twice alike is two positions)
  defp attribute(rec, names) do
    for name <- names,
        {time, _n, {_input, outputs}} <- rec.traces[name],
        is_list(outputs),
        {:out, ref, _opts} <- outputs,
        reduce: MapSet.new() do
      set ->
        case Recording.resolve(rec, ref, time, set) do
          {:ok, i, _tuple} when is_integer(i) -> MapSet.put(set, i)
          _whole_or_missing -> set
        end
    end
  end

  defp items(rec, names, left_out) do
    feed =
      for i <- 0..(tuple_size(rec.tuples) - 1)//1,
          not MapSet.member?(left_out, i),
          {time, tuple} = Recording.tuple_at(rec, i),
          fed?(tuple),
          do: {time, 0, {:feed, tuple}}

    calls =
      for name <- names,
          {time, _n, _event} = traced <- rec.traces[name],
          do: {time, 1, {:call, name, traced}}

    Enum.sort_by(feed ++ calls, fn {time, order, _} -> {time, order} end)
  end

  defp fed?({tag, _id, _payload}), do: tag not in @not_fed
  defp fed?(_tuple), do: true

  defp item({time, _, what}, acc, rec, start, speed, step) do
    seconds = (time - start.first) / 1.0e9

    case ask(step, acc, seconds, what) do
      :stop ->
        {:halt, acc}

      {:go, acc} ->
        wait(start, seconds, speed, step)
        {:cont, run_item(what, acc, rec)}
    end
  end

  defp ask(nil, acc, _seconds, _what), do: {:go, acc}
  defp ask(_step, %{skip: n} = acc, _seconds, _what) when n > 0, do: {:go, %{acc | skip: n - 1}}

  defp ask(step, acc, seconds, what) do
    case step.(%{time: seconds, text: text(what)}) do
      :stop -> :stop
      {:skip, n} when is_integer(n) and n >= 0 -> {:go, %{acc | skip: n}}
      _continue -> {:go, acc}
    end
  end

  # a stepped replay goes at the pace of its steps
  defp wait(_start, _seconds, :max, _step), do: :ok
  defp wait(_start, _seconds, _speed, step) when step != nil, do: :ok

  defp wait(start, seconds, speed, nil) do
    due = start.wall + round(seconds * 1000 / speed)
    left = due - System.monotonic_time(:millisecond)
    if left > 0, do: Process.sleep(left)
    :ok
  end

  defp run_item({:feed, tuple}, acc, _rec) do
    case tuple do
      {_tag, _id, _payload} -> Blackboard.out(tuple, key: ThinkingCap.Tuples.key(tuple))
      _ -> Blackboard.out(tuple)
    end

    %{acc | fed: acc.fed + 1}
  end

  defp run_item({:call, name, traced}, acc, rec) do
    {cmp, effects} = Comparison.step(acc.cmps[name], rec, traced)
    for {:out, tuple, opts} <- effects, do: Blackboard.out(tuple, opts)
    %{acc | cmps: Map.put(acc.cmps, name, cmp)}
  end

  defp text({:feed, tuple}), do: "fed " <> inspect(tuple, limit: 6, printable_limit: 60)

  defp text({:call, name, {_time, n, {input, _outputs}}}),
    do: "#{name} callback #{n}: #{inspect(input, limit: 6, printable_limit: 60)}"
end
