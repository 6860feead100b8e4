defmodule ThinkingCap.BlackBox.Core.Comparison do
  @moduledoc false
  # One module run again on its recorded trace, callback by callback
  # (ThinkingCap.Module.Core.Rerun), each callback's outputs compared with
  # the recorded ones, in order. An output is one effect (a tuple written,
  # the cycle's command, a subscription, a param set), or a refusal, or
  # what the callback raised. Equal means equal as terms; a module's
  # declared measurements (ThinkingCap.Module.replay/0) are left out of
  # the comparison of the tuples they are in, and such outputs counted
  # apart (`measured`).
  #
  # The run stops, saying why, where it cannot go on identically: the
  # recording began after the module started, callbacks are missing from
  # it, or an input tuple is (the recorder dropped it, or its templates
  # left it out).

  alias ThinkingCap.BlackBox.Core.Recording
  alias ThinkingCap.Module.Core.Rerun
  alias ThinkingCap.Runtime.Trace

  defstruct [
    :name,
    :module,
    :rerun,
    measurements: [],
    next: 0,
    started: false,
    callbacks: 0,
    outputs: 0,
    equal: 0,
    measured: 0,
    differences: [],
    difference_count: 0,
    restarts: 0,
    stopped: nil
  ]

  @type t :: %__MODULE__{}

  # differences kept for the report (all are counted)
  @kept 10

  @spec new(atom()) :: t()
  def new(name), do: %__MODULE__{name: name}

  # Runs one traced callback `{time, n, {input, recorded}}`; gives the
  # replayed effects (what the module wrote this time).
  @spec step(t(), Recording.t(), {integer(), non_neg_integer(), Trace.event()}) ::
          {t(), [term()]}
  def step(%{stopped: stopped} = cmp, _rec, _traced) when stopped != nil, do: {cmp, []}

  def step(cmp, rec, {time, n, {{:init, info}, recorded}}) when n == 0 do
    cmp =
      if cmp.started,
        do: %{cmp | restarts: cmp.restarts + 1},
        else: %{cmp | started: true}

    if module?(info.module) do
      {rerun, outcome} = Rerun.init(cmp.name, info)

      cmp = %{
        cmp
        | module: info.module,
          rerun: rerun,
          measurements: Trace.measurements(info.module),
          next: 1
      }

      compare(cmp, rec, time, n, {:init, info.module}, recorded, outcome)
    else
      {stop(
         %{cmp | module: info.module},
         "#{inspect(info.module)} is not a ThinkingCap.Module here (not loaded, or not one): " <>
           "#{inspect(cmp.name)} cannot be run again"
       ), []}
    end
  end

  def step(%{started: false} = cmp, _rec, {_time, n, _event}) do
    {stop(
       cmp,
       "the recording began after #{inspect(cmp.name)} started (its first callback " <>
         "recorded is its #{n}th since init): it cannot be run again from its start"
     ), []}
  end

  def step(%{next: next} = cmp, _rec, {_time, n, _event}) when n != next do
    {stop(cmp, "callbacks #{next} to #{n - 1} of #{inspect(cmp.name)} are not in the recording"),
     []}
  end

  def step(%{rerun: nil} = cmp, _rec, _traced) do
    {stop(cmp, "#{inspect(cmp.name)} raised in init/2 and the recording has no restart"), []}
  end

  def step(cmp, rec, {time, n, {{:swap, module}, _recorded} = event}) do
    if module?(module),
      do: run(cmp, rec, time, n, event),
      else:
        {stop(
           cmp,
           "#{inspect(cmp.name)} was swapped to #{inspect(module)}, not a ThinkingCap.Module here"
         ), []}
  end

  def step(cmp, rec, {time, n, event}), do: run(cmp, rec, time, n, event)

  # the code a recording names is run only when it is a module's
  defp module?(module) do
    behaviours =
      if Code.ensure_loaded?(module),
        do: module.module_info(:attributes) |> Keyword.get_values(:behaviour) |> List.flatten(),
        else: []

    ThinkingCap.Module in behaviours
  end

  defp run(cmp, rec, time, n, {input, recorded}) do
    case found(rec, input, time) do
      {:ok, input} ->
        {rerun, outcome} = Rerun.call(cmp.rerun, input)

        compare(
          %{cmp | rerun: rerun, next: n + 1},
          rec,
          time,
          n,
          describe(input),
          recorded,
          outcome
        )

      {:missing, tag} ->
        {stop(
           cmp,
           "a #{inspect(tag)} tuple #{inspect(cmp.name)} received (callback #{n}) is not in " <>
             "the recording (the recorder dropped it, or its templates left it out)"
         ), []}
    end
  end

  defp found(rec, {:tuple, {:hash, tag, _} = ref}, time) do
    case Recording.resolve(rec, ref, time) do
      {:ok, _i, tuple} -> {:ok, {:tuple, tuple}}
      :missing -> {:missing, tag}
    end
  end

  defp found(_rec, {:tuple, {:term, tuple}}, _time), do: {:ok, {:tuple, tuple}}
  defp found(_rec, input, _time), do: {:ok, input}

  defp stop(cmp, why), do: %{cmp | stopped: why}

  defp compare(cmp, rec, time, n, input, recorded, outcome) do
    robot = rec.robot
    replayed = Rerun.traced(outcome, robot)
    effects = with {:ok, effects} <- outcome, do: effects, else: (_ -> [])

    results =
      if is_list(recorded) and is_list(replayed) do
        count = max(length(recorded), length(replayed))

        for i <- 0..(count - 1)//1 do
          r = Enum.at(recorded, i)
          p = Enum.at(replayed, i)
          result(cmp, rec, time, r, p, Enum.at(effects, i))
        end
      else
        [if(recorded == replayed, do: :equal, else: {:differs, recorded, replayed})]
      end

    cmp = %{cmp | callbacks: cmp.callbacks + 1, outputs: cmp.outputs + length(results)}

    cmp =
      Enum.reduce(results, cmp, fn
        :equal, cmp ->
          %{cmp | equal: cmp.equal + 1}

        :measured, cmp ->
          %{cmp | equal: cmp.equal + 1, measured: cmp.measured + 1}

        {:differs, r, p}, cmp ->
          difference = %{
            callback: n,
            time: time,
            input: input,
            recorded: show(rec, r, time),
            replayed: p
          }

          %{
            cmp
            | difference_count: cmp.difference_count + 1,
              differences:
                if(length(cmp.differences) < @kept,
                  do: cmp.differences ++ [difference],
                  else: cmp.differences
                )
          }
      end)

    {cmp, effects}
  end

  defp result(_cmp, _rec, _time, same, same, _effect), do: :equal

  defp result(cmp, rec, time, {:out, ref, opts} = r, {:out, _, opts}, {:out, tuple, opts})
       when cmp.measurements != [] do
    with {:ok, _i, recorded} <- Recording.resolve(rec, ref, time),
         true <- mask(recorded, cmp.measurements) == mask(tuple, cmp.measurements) do
      :measured
    else
      _ -> {:differs, r, {:out, tuple, opts}}
    end
  end

  defp result(_cmp, _rec, _time, r, _p, {:out, tuple, opts}),
    do: {:differs, r, {:out, tuple, opts}}

  defp result(_cmp, _rec, _time, r, p, _effect), do: {:differs, r, p}

  # a recorded output with its tuple found, for a report
  defp show(rec, {:out, ref, opts}, time) do
    case Recording.resolve(rec, ref, time) do
      {:ok, _i, tuple} -> {:out, tuple, opts}
      :missing -> {:out, ref, opts}
    end
  end

  defp show(_rec, other, _time), do: other

  defp describe({:tuple, tuple}) when is_tuple(tuple) and tuple_size(tuple) >= 1,
    do: {:tuple, elem(tuple, 0)}

  defp describe({kind, _}) when is_atom(kind), do: kind
  defp describe({kind, _, _}) when is_atom(kind), do: kind
  defp describe(input), do: input

  @doc false
  # A tuple with the measured parts of its payload replaced by :measured.
  @spec mask(tuple(), [{atom(), [term()]}]) :: tuple()
  def mask({tag, id, payload} = tuple, measurements) do
    case for {^tag, path} <- measurements, do: path do
      [] -> tuple
      paths -> {tag, id, Enum.reduce(paths, payload, &drop/2)}
    end
  end

  def mask(tuple, _measurements), do: tuple

  defp drop([key], map) when is_map(map) and is_map_key(map, key),
    do: Map.put(map, key, :measured)

  defp drop([key | rest], map) when is_map(map) and is_map_key(map, key),
    do: Map.update!(map, key, &drop(rest, &1))

  defp drop(_path, other), do: other

  # The comparison as reported.
  @spec report(t()) :: map()
  def report(cmp) do
    %{
      name: cmp.name,
      module: cmp.module,
      callbacks: cmp.callbacks,
      outputs: cmp.outputs,
      equal: cmp.equal,
      measured: cmp.measured,
      differences: cmp.difference_count,
      first_differences: cmp.differences,
      restarts: cmp.restarts,
      stopped: cmp.stopped,
      identical: cmp.difference_count == 0 and cmp.stopped == nil and cmp.callbacks > 0
    }
  end
end
