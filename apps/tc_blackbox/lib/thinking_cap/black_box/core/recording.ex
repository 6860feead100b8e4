defmodule ThinkingCap.BlackBox.Core.Recording do
  @moduledoc false
  # A recording read for a replay: one robot's files (a recording rotated
  # into several, or one dump), their whole tuples (`/etf/...`) in log
  # time order, an index to find a tuple a trace names by its tag and hash
  # (ThinkingCap.Runtime.Trace.ref/2), and each module's traced callbacks.

  alias ThinkingCap.BlackBox.Core.{Channels, Terms}
  alias ThinkingCap.MCAP.Reader
  alias ThinkingCap.Runtime.Trace

  defstruct robot: nil,
            files: [],
            tuples: {},
            index: %{},
            traces: %{},
            first: nil,
            last: nil

  @type t :: %__MODULE__{
          robot: atom(),
          files: [Path.t()],
          # {log_time, tuple}, by position
          tuples: tuple(),
          index: %{{term(), non_neg_integer()} => [non_neg_integer()]},
          # module name => [{log_time, n, event}], oldest first
          traces: %{atom() => [{integer(), non_neg_integer(), Trace.event()}]},
          first: integer() | nil,
          last: integer() | nil
        }

  # new atoms a recording may make (robot, module and place names...)
  @atom_budget 10_000

  @spec read([Path.t()], String.t() | nil) :: {:ok, t()} | {:error, String.t()}
  def read([], _robot), do: {:error, "no recording given"}

  def read(paths, robot) do
    with {:ok, files} <- read_files(paths),
         {:ok, robot, files} <- pick(files, robot),
         :ok <- exact(files),
         {:ok, tuples, traces, budget} <- decode(files, @atom_budget),
         {:ok, robot, _budget} <- atom(robot, budget) do
      times = Enum.map(tuples, &elem(&1, 0)) ++ Enum.map(traces, &elem(&1, 0))

      {:ok,
       %__MODULE__{
         robot: robot,
         files: Enum.map(files, & &1.path),
         tuples: List.to_tuple(tuples),
         index: index(tuples),
         traces: traces |> Enum.group_by(&elem(&1, 3), &Tuple.delete_at(&1, 3)),
         first: Enum.min(times, fn -> nil end),
         last: Enum.max(times, fn -> nil end)
       }}
    end
  end

  defp read_files(paths) do
    Enum.reduce_while(paths, {:ok, []}, fn path, {:ok, acc} ->
      case Reader.read(path) do
        {:ok, mcap} ->
          {:cont, {:ok, [%{path: path, mcap: mcap, robots: robots(mcap)} | acc]}}

        {:error, :enoent} ->
          {:halt, {:error, "#{path}: no such file"}}

        {:error, reason} ->
          {:halt, {:error, "#{path}: not a readable MCAP file (#{inspect(reason)})"}}
      end
    end)
    |> case do
      {:ok, files} -> {:ok, Enum.reverse(files)}
      error -> error
    end
  end

  defp robots(mcap) do
    for {_, c} <- mcap.channels, robot = c.metadata["robot"], uniq: true, do: robot
  end

  # the files of one robot: the one asked for, or the only one there is
  defp pick(files, robot) do
    all = files |> Enum.flat_map(& &1.robots) |> Enum.uniq() |> Enum.sort()

    cond do
      robot != nil and robot not in all ->
        {:error,
         "no recording of robot #{robot} in #{Enum.map_join(files, ", ", & &1.path)} " <>
           "(robots: #{Enum.join(all, ", ")})"}

      robot == nil and length(all) > 1 ->
        {:error, "the files hold several robots (#{Enum.join(all, ", ")}): choose one (--robot)"}

      all == [] ->
        {:error, "#{Enum.map_join(files, ", ", & &1.path)}: no robot's channels"}

      true ->
        robot = robot || hd(all)
        {:ok, robot, Enum.filter(files, &(robot in &1.robots))}
    end
  end

  defp exact(files) do
    case Enum.reject(files, &has_terms?/1) do
      [] ->
        :ok

      [file | _] ->
        {:error,
         "#{file.path}: no whole terms (no /etf/ channels): it was recorded before " <>
           "recordings kept them, and can be viewed (Foxglove) but not replayed"}
    end
  end

  defp has_terms?(file),
    do: Enum.any?(file.mcap.channels, fn {_, c} -> c.message_encoding == Channels.encoding() end)

  # every message of the etf channels, decoded: tuples and traced callbacks
  defp decode(files, budget) do
    messages =
      for file <- files,
          channel = file.mcap.channels,
          m <- file.mcap.messages,
          c = channel[m.channel_id],
          c.message_encoding == Channels.encoding(),
          do: {m.log_time, c, m}

    messages
    |> Enum.sort_by(&elem(&1, 0))
    |> Enum.reduce_while({:ok, [], [], budget}, fn {time, c, m}, {:ok, ts, tr, budget} ->
      case Terms.decode(m.data, budget) do
        {:ok, term, budget} ->
          case kind(c, term) do
            :tuple ->
              {:cont, {:ok, [{time, term} | ts], tr, budget}}

            :other ->
              {:cont, {:ok, ts, tr, budget}}

            {:trace, nil} ->
              {:halt, {:error, not_traced(c, m, term)}}

            {:trace, name} ->
              case atom(name, budget) do
                {:ok, name, budget} ->
                  traced = for {n, us, event} <- term, do: {time + us * 1000, n, event, name}
                  {:cont, {:ok, ts, Enum.reverse(traced, tr), budget}}

                {:error, message} ->
                  {:halt, {:error, "#{c.topic}: #{message}"}}
              end
          end

        {:error, message} ->
          {:halt, {:error, "#{c.topic} (log time #{time}): #{message}"}}
      end
    end)
    |> case do
      {:ok, ts, tr, budget} -> {:ok, Enum.reverse(ts), Enum.reverse(tr), budget}
      error -> error
    end
  end

  defp kind(%{topic: "/etf/" <> _}, term) when is_tuple(term), do: :tuple

  defp kind(%{topic: "/trace/" <> _, metadata: %{"module" => name}}, events) do
    if is_list(events) and events != [] and Enum.all?(events, &traced?/1),
      do: {:trace, name},
      else: {:trace, nil}
  end

  defp kind(_channel, _term), do: :other

  defp not_traced(c, m, term),
    do:
      "#{c.topic} (sequence #{m.sequence}): not a list of traced callbacks: " <>
        inspect(term, limit: 5, printable_limit: 60)

  # `{n, us, callback}`, the callback as ThinkingCap.Runtime.Trace sends
  # it: a file may hold anything
  defp traced?({n, us, {input, outputs}})
       when is_integer(n) and n >= 0 and is_integer(us) and us >= 0,
       do: input?(input) and outputs?(outputs)

  defp traced?(_other), do: false

  defp input?({:init, %{module: m, params: p, context: %{robot: r}, activity: a}})
       when is_atom(m) and (is_list(p) or is_map(p) or p == nil) and is_atom(r) and is_atom(a),
       do: true

  defp input?({:tuple, {:hash, _tag, h}}) when is_integer(h), do: true
  defp input?({:tuple, {:term, t}}) when is_tuple(t), do: true
  defp input?({:cycle, %{}}), do: true
  defp input?({:applied, %{}}), do: true
  defp input?({:param, key, _value}) when is_atom(key), do: true
  defp input?(:background), do: true
  defp input?({:info, _message}), do: true
  defp input?({:swap, m}) when is_atom(m), do: true
  defp input?(_other), do: false

  defp outputs?(list) when is_list(list), do: true
  defp outputs?({:refused, m}) when is_binary(m), do: true
  defp outputs?({:raised, k, m}) when is_atom(k) and is_binary(m), do: true
  defp outputs?(_other), do: false

  # a robot's or a module's name, counted against the atom budget
  defp atom(name, budget) do
    {:ok, String.to_existing_atom(name), budget}
  rescue
    ArgumentError ->
      if budget > 0 and byte_size(name) <= 255,
        do: {:ok, String.to_atom(name), budget - 1},
        else: {:error, "#{inspect(name)}: too many names unknown to this VM"}
  end

  defp index(tuples) do
    tuples
    |> Enum.with_index()
    |> Enum.reduce(%{}, fn {{_time, tuple}, i}, index ->
      Map.update(index, {tag(tuple), Trace.hash(tuple)}, [i], &[i | &1])
    end)
  end

  defp tag({tag, _id, _payload}), do: tag
  defp tag(_other), do: nil

  # The tuple a trace names at `time`: the recorded tuple of that tag and
  # hash nearest in time (hashes that agree, within a few seconds, are the
  # same tuple but for a chance of one in four billion per pair), with its
  # position; or whole when the trace has it whole.
  # Positions in `taken` are passed over.
  @spec resolve(t(), Trace.ref(), integer(), MapSet.t()) ::
          {:ok, non_neg_integer() | nil, tuple()} | :missing
  def resolve(rec, ref, time, taken \\ MapSet.new())
  def resolve(_rec, {:term, tuple}, _time, _taken), do: {:ok, nil, tuple}

  def resolve(rec, {:hash, tag, hash}, time, taken) do
    case Enum.reject(Map.get(rec.index, {tag, hash}, []), &MapSet.member?(taken, &1)) do
      [] ->
        :missing

      positions ->
        i = Enum.min_by(positions, &abs(elem(elem(rec.tuples, &1), 0) - time))
        {:ok, i, elem(elem(rec.tuples, i), 1)}
    end
  end

  @spec tuple_at(t(), non_neg_integer()) :: {integer(), tuple()}
  def tuple_at(rec, i), do: elem(rec.tuples, i)
end
