defmodule ThinkingCap.Config.Schema do
  @moduledoc """
  The small schema language the description-file readers validate with,
  and the one place their keys, types and defaults are documented
  (`describe/1` renders a schema as the tables in `ThinkingCap.Config.ADF`,
  `ThinkingCap.Config.RDF` and `ThinkingCap.Config.WDF`).

  A schema is data. A field is `{type, opts}` with `required: true` or
  `default: value` and `doc: "..."`; a module's param (`c:ThinkingCap.Module.params/0`)
  may add `read_only: true`: it is set in the ADF and read when the module
  starts, never changed while it runs (live parameters refuse it). Types:

    * scalars: `:atom`, `:string`, `:path` (a file name: a non-empty
      string of at most 4096 bytes without a NUL byte), `:boolean`,
      `:module`, `:number`,
      `:pos_number`, `:non_neg_number`, `:probability` (0..1), `:integer`,
      `:pos_integer`, `:non_neg_integer`, `:port`, `{:int_range, min, max}`,
      `{:number_range, min, max}`, `{:one_of, values}`, `:any`;
    * `:place`: the name (an atom) of a waypoint, room, corridor or door
      of the run's WDF, when the WDF is known (`check_at/4` with the
      names in the state's `places`);
    * `{:tuple, types}` (a tuple of those types, in order) and
      `{:or, types}` (the first type that takes the value);
    * geometry: `:point` `{x, y}`, `:pose` `{x, y, theta}`,
      `:point_or_pose`, `:segment` `{{x1, y1}, {x2, y2}}`, `:range`
      `{min, max}` with min < max;
    * `:template` (a blackboard template: a tuple);
    * `:params` (a keyword list or a map, passed on as it is);
    * `{:list, type}`; `{:keyword, fields}` (known keys, validated into a
      map); `{:keyword_of, type}` (any atom keys, in order: `[{key, value}]`).

  Validation collects every error, each at the position of the value (or
  key) it concerns.
  """

  alias ThinkingCap.Config.Error

  @type type :: atom() | tuple()
  @type field :: {type(), keyword()}
  @type fields :: [{atom(), field()}]

  @typedoc false
  @type state :: %{file: Path.t(), positions: map(), errors: [Error.t()]}

  @doc """
  Validates `value` against `type`. Returns the validated value (keyword
  lists of known keys become maps with defaults filled in) and the errors.
  """
  @spec validate(term(), type(), Path.t(), map()) :: {term(), [Error.t()]}
  def validate(value, type, file, positions) do
    {value, st} = check(type, value, [], %{file: file, positions: positions, errors: []})
    {value, Enum.reverse(st.errors)}
  end

  @doc """
  Validates a description file's data against its top-level `fields` and
  returns the value and the checking state, for the kind's checks across
  keys (`error/3`); `errors/1` gives the result.
  """
  @spec start(term(), fields(), Path.t(), map()) :: {term(), state()}
  def start(data, fields, file, positions) do
    {value, errors} = validate(data, {:keyword, fields}, file, positions)
    {value, %{file: file, positions: positions, errors: Enum.reverse(errors)}}
  end

  @doc "Whether `value` is taken as a `:path`: a file name that can be opened."
  @spec file_name?(term()) :: boolean()
  def file_name?(value),
    do:
      is_binary(value) and value != "" and byte_size(value) <= 4096 and
        not String.contains?(value, <<0>>)

  @doc """
  Validates `value` at `path` of a file being checked (a module's params,
  say) against `type`, adding its errors to the checking state. With
  `places` (a MapSet of names) in the state, `:place` values must be
  among them.
  """
  @spec check_at(state(), type(), term(), list()) :: {term(), state()}
  def check_at(st, type, value, path), do: check(type, value, path, st)

  @doc "The errors of a checking state, in order."
  @spec errors(state()) :: [Error.t()]
  def errors(st), do: Enum.reverse(st.errors)

  @doc "Adds an error about the value at `path` (used for checks across fields)."
  @spec error(state(), list(), String.t()) :: state()
  def error(st, path, message),
    do: %{st | errors: [Error.new(st.file, position(st, path), message) | st.errors]}

  @doc "The position of the value at `path`, or of its nearest enclosing value."
  @spec position(state() | map(), list()) :: {non_neg_integer(), non_neg_integer()}
  def position(%{positions: positions}, path), do: position(positions, path)

  def position(positions, path) do
    Map.get(positions, path) ||
      case path do
        [] -> {1, 1}
        _ -> position(positions, Enum.drop(path, -1))
      end
  end

  @doc "A path as users read it: `modules.base.period`, `sensors[2].range`."
  @spec path_string(list()) :: String.t()
  def path_string([]), do: "the file"

  def path_string(path) do
    Enum.reduce(path, "", fn
      i, "" when is_integer(i) -> "[#{i}]"
      i, acc when is_integer(i) -> acc <> "[#{i}]"
      key, "" -> to_string(key)
      key, acc -> acc <> "." <> to_string(key)
    end)
  end

  @doc "The defaults of `fields` as a keyword list (nil where a field has none)."
  @spec defaults(fields()) :: keyword()
  def defaults(fields), do: for({key, {_type, opts}} <- fields, do: {key, opts[:default]})

  @doc "Renders `fields` as a Markdown table: key, type, default, meaning."
  @spec describe(fields()) :: String.t()
  def describe(fields) do
    rows =
      for {key, {type, opts}} <- fields do
        default =
          cond do
            opts[:required] -> "required"
            Keyword.has_key?(opts, :default) -> "`#{inspect(opts[:default])}`"
            true -> "optional"
          end

        read_only = if opts[:read_only], do: " (read-only while running)", else: ""
        "| `#{key}` | #{type_name(type)} | #{default} | #{opts[:doc]}#{read_only} |"
      end

    Enum.join(["| key | type | default | meaning |", "|---|---|---|---|" | rows], "\n")
  end

  ## Checking

  defp check({:keyword, fields}, value, path, st) do
    if keyword?(value) do
      st = check_keys(value, fields, path, st)

      Enum.reduce(fields, {%{}, st}, fn {key, {type, opts}}, {map, st} ->
        case Keyword.fetch(value, key) do
          {:ok, v} ->
            {v, st} = check(type, v, path ++ [key], st)
            {Map.put(map, key, v), st}

          :error ->
            cond do
              opts[:required] ->
                {map, error(st, path, "#{path_string(path)}: missing required key :#{key}")}

              Keyword.has_key?(opts, :default) ->
                with(
                  {v, st} <- default(type, opts[:default], path ++ [key], st),
                  do: {Map.put(map, key, v), st}
                )

              true ->
                {Map.put(map, key, nil), st}
            end
        end
      end)
    else
      {%{}, expected(st, path, "a keyword list like [key: value, ...]", value)}
    end
  end

  defp check({:keyword_of, type}, value, path, st) do
    if keyword?(value) do
      st = check_duplicates(value, path, st)

      Enum.map_reduce(value, st, fn {k, v}, st ->
        with({v, st} <- check(type, v, path ++ [k], st), do: {{k, v}, st})
      end)
    else
      {[], expected(st, path, "a keyword list of name: value entries", value)}
    end
  end

  defp check({:list, type}, value, path, st) when is_list(value) do
    value
    |> Enum.with_index()
    |> Enum.map_reduce(st, fn {v, i}, st -> check(type, v, path ++ [i], st) end)
  end

  defp check({:list, _type}, value, path, st), do: {[], expected(st, path, "a list", value)}

  defp check({:one_of, values}, value, path, st) do
    if value in values,
      do: {value, st},
      else:
        {value, expected(st, path, "one of #{Enum.map_join(values, ", ", &inspect/1)}", value)}
  end

  defp check({:int_range, min, max}, value, path, st) do
    if is_integer(value) and value >= min and value <= max,
      do: {value, st},
      else: {value, expected(st, path, "an integer from #{min} to #{max}", value)}
  end

  defp check(:port, value, path, st), do: check({:int_range, 1, 65_535}, value, path, st)

  defp check({:number_range, min, max}, value, path, st) do
    if is_number(value) and value >= min and value <= max,
      do: {value / 1, st},
      else: {value, expected(st, path, "a number from #{min} to #{max}", value)}
  end

  defp check({:tuple, types}, value, path, st)
       when is_tuple(value) and tuple_size(value) == length(types) do
    {values, st} =
      types
      |> Enum.zip(Tuple.to_list(value))
      |> Enum.with_index()
      |> Enum.map_reduce(st, fn {{type, v}, i}, st -> check(type, v, path ++ [i], st) end)

    {List.to_tuple(values), st}
  end

  defp check({:tuple, types}, value, path, st),
    do:
      {value, expected(st, path, "a tuple {#{Enum.map_join(types, ", ", &type_name/1)}}", value)}

  # a name where a place may stand: said as a place that is not there
  defp check({:or, types}, value, path, st) do
    if is_atom(value) and value not in [nil, true, false] and :place in types,
      do: check(:place, value, path, st),
      else: check_either(types, value, path, st)
  end

  defp check(:place, value, path, st) when is_atom(value) and value not in [nil, true, false] do
    case Map.get(st, :places) do
      nil ->
        {value, st}

      places ->
        if MapSet.member?(places, value),
          do: {value, st},
          else: {value, error(st, path, "#{path_string(path)}: #{unknown_place(value, places)}")}
    end
  end

  defp check(:place, value, path, st),
    do: {value, expected(st, path, "the name of a waypoint, room or door, like :dock", value)}

  defp check(:point, value, path, st) do
    case value do
      {x, y} when is_number(x) and is_number(y) -> {{x / 1, y / 1}, st}
      _ -> {value, expected(st, path, "a point {x, y} in metres", value)}
    end
  end

  defp check(:pose, value, path, st) do
    case value do
      {x, y, t} when is_number(x) and is_number(y) and is_number(t) -> {{x / 1, y / 1, t / 1}, st}
      _ -> {value, expected(st, path, "a pose {x, y, theta} in metres and radians", value)}
    end
  end

  defp check(:point_or_pose, value, path, st) do
    case value do
      {_, _} -> check(:point, value, path, st)
      _ -> check(:pose, value, path, st)
    end
  end

  defp check(:segment, value, path, st) do
    case value do
      {{x1, y1}, {x2, y2}}
      when is_number(x1) and is_number(y1) and is_number(x2) and is_number(y2) ->
        {{{x1 / 1, y1 / 1}, {x2 / 1, y2 / 1}}, st}

      _ ->
        {value, expected(st, path, "a segment {{x1, y1}, {x2, y2}} in metres", value)}
    end
  end

  defp check(:range, value, path, st) do
    case value do
      {min, max} when is_number(min) and is_number(max) and min >= 0 and min < max ->
        {{min / 1, max / 1}, st}

      _ ->
        {value, expected(st, path, "a range {min, max} with 0 <= min < max", value)}
    end
  end

  defp check(:template, value, path, st) when is_tuple(value) do
    ThinkingCap.Blackboard.Template.compile(value)
    {value, st}
  rescue
    e in ArgumentError ->
      {value, error(st, path, "#{path_string(path)}: #{Exception.message(e)}")}
  end

  defp check(:template, value, path, st),
    do: {value, expected(st, path, "a blackboard template (a tuple)", value)}

  defp check(:params, value, path, st) do
    if keyword?(value) or is_map(value),
      do: {value, st},
      else: {value, expected(st, path, "parameters as a keyword list or a map", value)}
  end

  defp check(:any, value, _path, st), do: {value, st}

  defp check(scalar, value, path, st) do
    {ok, expectation} = scalar_check(scalar, value)

    if ok,
      do: {normalize(scalar, value), st},
      else: {value, expected(st, path, expectation, value)}
  end

  # the first of `types` that takes the value
  defp check_either(types, value, path, st) do
    Enum.find_value(types, fn type ->
      case check(type, value, path, %{st | errors: []}) do
        {v, %{errors: []}} -> {v, st}
        _ -> nil
      end
    end) || either_failed(types, value, path, st)
  end

  # None took the value. A tagged tuple whose tag and size one of them
  # takes (`{:patrol, [...]}` for `{:tuple, [{:one_of, [:patrol]}, _]}`)
  # is said in that one's words: what is wrong inside it.
  defp either_failed(types, value, path, st) do
    case Enum.filter(types, &tagged_as?(&1, value, path, st)) do
      [type] -> check(type, value, path, st)
      _ -> {value, expected(st, path, Enum.map_join(types, " or ", &type_name/1), value)}
    end
  end

  defp tagged_as?({:tuple, [tag | _] = types}, value, path, st)
       when is_tuple(value) and tuple_size(value) == length(types) do
    match?({_, %{errors: []}}, check(tag, elem(value, 0), path, %{st | errors: []}))
  end

  defp tagged_as?(_type, _value, _path, _st), do: false

  # a nested keyword default is expanded with its own fields' defaults
  defp default({:keyword, _} = type, default, path, st), do: check(type, default, path, st)
  defp default(_type, default, _path, st), do: {default, st}

  defp scalar_check(:atom, v),
    do: {is_atom(v) and v not in [nil, true, false], "an atom like :name"}

  defp scalar_check(:string, v), do: {is_binary(v), "a string"}

  defp scalar_check(:path, v),
    do:
      {file_name?(v),
       "a file name (a non-empty string of at most 4096 bytes, without a NUL byte)"}

  defp scalar_check(:boolean, v), do: {is_boolean(v), "true or false"}

  defp scalar_check(:module, v),
    do: {is_atom(v) and module_name?(v), "a module name like ThinkingCap.Sim.Robot"}

  defp scalar_check(:number, v), do: {is_number(v), "a number"}
  defp scalar_check(:pos_number, v), do: {is_number(v) and v > 0, "a positive number"}
  defp scalar_check(:non_neg_number, v), do: {is_number(v) and v >= 0, "a number >= 0"}

  defp scalar_check(:probability, v),
    do: {is_number(v) and v >= 0 and v <= 1, "a probability from 0 to 1"}

  defp scalar_check(:integer, v), do: {is_integer(v), "an integer"}
  defp scalar_check(:pos_integer, v), do: {is_integer(v) and v > 0, "a positive integer"}
  defp scalar_check(:non_neg_integer, v), do: {is_integer(v) and v >= 0, "an integer >= 0"}

  defp normalize(type, v) when type in [:number, :pos_number, :non_neg_number, :probability],
    do: v / 1

  defp normalize(_type, v), do: v

  defp module_name?(atom), do: String.starts_with?(Atom.to_string(atom), "Elixir.")

  defp keyword?(value),
    do: is_list(value) and Enum.all?(value, &match?({k, _} when is_atom(k), &1))

  defp check_keys(value, fields, path, st) do
    known = Keyword.keys(fields)
    st = check_duplicates(value, path, st)

    Enum.reduce(value, st, fn {key, _}, st ->
      if key in known do
        st
      else
        pos = Map.get(st.positions, {:key, path ++ [key]}) || position(st, path ++ [key])
        hint = did_you_mean(key, known)

        message =
          "unknown key :#{key} in #{path_string(path)}#{hint}; known keys: #{Enum.map_join(known, ", ", &":#{&1}")}"

        %{st | errors: [Error.new(st.file, pos, message) | st.errors]}
      end
    end)
  end

  defp check_duplicates(value, path, st) do
    {_, st} =
      Enum.reduce(value, {MapSet.new(), st}, fn {key, _}, {seen, st} ->
        if MapSet.member?(seen, key) do
          pos = Map.get(st.positions, {:key, path ++ [key]}) || position(st, path)

          {seen,
           %{
             st
             | errors: [
                 Error.new(st.file, pos, "key :#{key} given twice in #{path_string(path)}")
                 | st.errors
               ]
           }}
        else
          {MapSet.put(seen, key), st}
        end
      end)

    st
  end

  defp unknown_place(name, places) do
    known = Enum.sort(places)

    "#{inspect(name)} is not a waypoint, room, corridor or door of the WDF#{did_you_mean(name, known)}" <>
      if known == [], do: " (it names none)", else: ""
  end

  defp did_you_mean(key, known) do
    case Enum.max_by(known, &String.jaro_distance(to_string(&1), to_string(key)), fn -> nil end) do
      nil ->
        ""

      best ->
        if String.jaro_distance(to_string(best), to_string(key)) >= 0.8,
          do: "; did you mean :#{best}?",
          else: ""
    end
  end

  defp expected(st, path, what, value) do
    error(
      st,
      path,
      "#{path_string(path)}: expected #{what}, got #{inspect(value, limit: 8, printable_limit: 40)}"
    )
  end

  @doc "A type as the tables of `describe/1` name it: `number 0.0..2.0`, `true or false`..."
  @spec type_name(type()) :: String.t()
  def type_name({:keyword, _}), do: "keyword list (below)"
  def type_name({:keyword_of, type}), do: "`name: #{type_name(type)}` entries"
  def type_name({:list, type}), do: "list of #{type_name(type)}"
  def type_name({:one_of, values}), do: Enum.map_join(values, " \\| ", &"`#{inspect(&1)}`")
  def type_name({:int_range, a, b}), do: "integer #{a}..#{b}"
  def type_name({:number_range, a, b}), do: "number #{a}..#{b}"
  def type_name({:tuple, types}), do: "{#{Enum.map_join(types, ", ", &type_name/1)}}"
  def type_name({:or, types}), do: Enum.map_join(types, " or ", &type_name/1)
  def type_name(:place), do: "waypoint, room or door name"
  def type_name(type), do: "#{type}"
end
