defmodule ThinkingCap.Blackboard.Template do
  @moduledoc """
  Templates select tuples on the blackboard.

  A template is either

    * a tuple of the same arity as the tuples it selects, each position a
      value that must be equal (`===`, so `1` does not match `1.0`) or the
      wildcard `:_`: `{:scan, :_, :_}` selects every robot's scans;

    * `{:spec, match_spec}`, an ETS match specification over the tuple
      itself, for guards: `{:spec, [{{:pose, :"$1", :_}, [{:is_atom, :"$1"}], [true]}]}`.
      A tuple is selected when the head and guards of any clause match; the
      body is ignored. A two-element template whose first element is `:spec`
      is always read as a match specification: to select tuples that start
      with the atom `:spec`, write the match specification for them.

  Literal values are matched exactly, whatever they contain: atoms such as
  `:_` or `:"$1"` nested inside a value, and maps (which ETS would match
  partially), are compared as values, not read as patterns.

  `compile/1` validates a template once and raises `ArgumentError` naming
  the problem; the result is used for every later match.
  """

  @enforce_keys [:source, :index, :matcher, :pattern, :guards]
  defstruct [:source, :index, :matcher, :pattern, :guards]

  @typedoc "A template as users write it."
  @type t :: tuple() | {:spec, :ets.match_spec()}

  @typedoc """
  Where subscriptions and waiters for a template are indexed: by arity and
  the first two elements (a stream: tag and robot id) when both are bound,
  by arity and first element when only that is, by arity alone when the
  first is a wildcard, and in one group for match specifications.
  """
  @type index ::
          {:stream, non_neg_integer(), term(), term()}
          | {:tag, non_neg_integer(), term()}
          | {:any, non_neg_integer()}
          | :spec

  @typedoc "The part of a compiled template that decides a match, small enough to store per subscription."
  @type matcher ::
          {:positions, non_neg_integer(), [{pos_integer(), term()}]} | {:spec, reference()}

  @typedoc "A validated template."
  @type compiled :: %__MODULE__{
          source: t(),
          index: index(),
          matcher: matcher(),
          pattern: tuple() | atom(),
          guards: list()
        }

  # Variables the store's own match specifications use; user match
  # specifications are told not to use them.
  @expires_var :"$0"

  @doc """
  Validates `template` and prepares it for matching.

  Raises `ArgumentError` when it is neither a tuple nor a valid
  `{:spec, match_spec}`.
  """
  @spec compile(t() | compiled()) :: compiled()
  def compile(%__MODULE__{} = compiled), do: compiled

  def compile({:spec, ms} = template), do: compile_spec(template, ms)

  def compile(template) when is_tuple(template) do
    arity = tuple_size(template)
    values = Tuple.to_list(template)

    bound = for {value, pos} <- Enum.with_index(values, 1), value !== :_, do: {pos, value}

    {pattern_elems, guards} =
      values
      |> Enum.with_index(1)
      |> Enum.map_reduce([], fn
        {:_, _pos}, acc ->
          {:_, acc}

        {value, pos}, acc ->
          if literal_pattern?(value) do
            {value, acc}
          else
            var = :"$#{pos}"
            {var, [{:"=:=", var, {:const, value}} | acc]}
          end
      end)

    %__MODULE__{
      source: template,
      index: index_of(template),
      matcher: {:positions, arity, bound},
      pattern: List.to_tuple(pattern_elems),
      guards: Enum.reverse(guards)
    }
  end

  def compile(other) do
    raise ArgumentError,
          "a blackboard template must be a tuple (positions are values or :_) or " <>
            "{:spec, match_spec}, got: #{inspect(other)}"
  end

  @doc "True when `tuple` is selected by the compiled template (or its matcher)."
  @spec matches?(compiled() | matcher(), tuple()) :: boolean()
  def matches?(%__MODULE__{matcher: matcher}, tuple), do: matches?(matcher, tuple)

  def matches?({:positions, arity, bound}, tuple) do
    tuple_size(tuple) == arity and positions_match?(bound, tuple)
  end

  def matches?({:spec, compiled_ms}, tuple) do
    :ets.match_spec_run([tuple], compiled_ms) != []
  end

  @doc """
  The matcher left to run on a tuple found under the template's index: the
  index already holds the arity and the elements it names (a hash lookup
  compares keys exactly), so those positions are not compared again.
  """
  @spec residual_matcher(compiled()) :: matcher()
  def residual_matcher(%__MODULE__{index: {:stream, _, _, _}, matcher: {:positions, n, bound}}),
    do: {:positions, n, Enum.reject(bound, fn {pos, _} -> pos <= 2 end)}

  def residual_matcher(%__MODULE__{index: {:tag, _, _}, matcher: {:positions, n, bound}}),
    do: {:positions, n, Enum.reject(bound, fn {pos, _} -> pos == 1 end)}

  def residual_matcher(%__MODULE__{matcher: matcher}), do: matcher

  @doc """
  The indexes under which templates that bind a tuple's first elements are
  found: its stream `{:stream, arity, first, second}` and its tag
  `{:tag, arity, first}` (as far as its arity allows). Templates indexed
  `{:any, arity}` or `:spec` may match any tuple.
  """
  @spec bound_indexes(tuple()) :: [index()]
  def bound_indexes(tuple) when tuple_size(tuple) >= 2 do
    n = tuple_size(tuple)
    first = elem(tuple, 0)
    [{:stream, n, first, elem(tuple, 1)}, {:tag, n, first}]
  end

  def bound_indexes({first}), do: [{:tag, 1, first}]
  def bound_indexes({}), do: []

  @doc """
  A match specification over the store's records `{key, tuple, _, expires, _}`
  (key `{arity, first, second, seq, owner}`, and `extra` more fields after
  them) that selects live records (not expired at `now`) whose tuple
  matches. The key pattern binds arity and the first two elements when the
  template does, so an ordered table only walks that range.
  """
  @spec record_match_spec(compiled(), integer(), term(), non_neg_integer()) :: :ets.match_spec()
  def record_match_spec(%__MODULE__{} = t, now, body \\ :"$_", extra \\ 0) do
    live = {:>, @expires_var, now}
    rest = List.duplicate(:_, extra)

    case t.matcher do
      {:positions, _arity, _bound} ->
        key = {key_arity(t), key_position(t, 1), key_position(t, 2), :_, :_}
        [{record_head(key, t.pattern, rest), [live | t.guards], [body]}]

      {:spec, _} ->
        {:spec, clauses} = t.source

        for {head, guards, _body} <- clauses do
          {record_head(:_, head, rest), [live | guards], [body]}
        end
    end
  end

  defp record_head(key, pattern, rest),
    do: List.to_tuple([key, pattern, :_, @expires_var, :_ | rest])

  ## Internals

  defp compile_spec(template, ms) do
    unless is_list(ms) and ms != [] and
             Enum.all?(ms, &match?({_, g, b} when is_list(g) and is_list(b), &1)) do
      raise ArgumentError,
            "{:spec, match_spec} needs a non-empty list of {head, guards, body} clauses, got: " <>
              inspect(template)
    end

    if Enum.any?(ms, fn {head, guards, _} -> uses_var?({head, guards}, @expires_var) end) do
      raise ArgumentError, "match specification variable #{inspect(@expires_var)} is reserved"
    end

    # The body is ignored: a clause selects when head and guards match.
    run_ms = for {head, guards, _body} <- ms, do: {head, guards, [true]}

    compiled =
      try do
        :ets.match_spec_compile(run_ms)
      rescue
        ArgumentError ->
          reraise ArgumentError,
                  "invalid ETS match specification in blackboard template: #{inspect(ms)}",
                  __STACKTRACE__
      end

    %__MODULE__{
      source: template,
      index: :spec,
      matcher: {:spec, compiled},
      pattern: :_,
      guards: []
    }
  end

  defp index_of({}), do: {:any, 0}
  defp index_of(template) when elem(template, 0) === :_, do: {:any, tuple_size(template)}

  defp index_of(template) when tuple_size(template) >= 2 and elem(template, 1) !== :_,
    do: {:stream, tuple_size(template), elem(template, 0), elem(template, 1)}

  defp index_of(template), do: {:tag, tuple_size(template), elem(template, 0)}

  defp key_arity(%__MODULE__{matcher: {:positions, arity, _}}), do: arity

  # The store's key holds the first two elements (tag and robot id by
  # convention), so binding them here lets an ordered table walk only their
  # range; a wildcard or a value ETS would read as a pattern stays unbound.
  defp key_position(%__MODULE__{source: source}, pos) when tuple_size(source) >= pos do
    value = elem(source, pos - 1)
    if value !== :_ and literal_pattern?(value), do: value, else: :_
  end

  defp key_position(%__MODULE__{}, _pos), do: :_

  defp positions_match?([], _tuple), do: true

  defp positions_match?([{pos, value} | rest], tuple) do
    :erlang.element(pos, tuple) === value and positions_match?(rest, tuple)
  end

  # A value can stand for itself in an ETS pattern when it holds no pattern
  # variables, no wildcards and no maps (ETS matches maps partially).
  defp literal_pattern?(value) when is_atom(value) do
    value != :_ and not String.starts_with?(Atom.to_string(value), "$")
  end

  defp literal_pattern?(value) when is_map(value), do: false

  defp literal_pattern?(value) when is_tuple(value),
    do: value |> Tuple.to_list() |> literal_pattern?()

  defp literal_pattern?([]), do: true
  defp literal_pattern?([h | t]), do: literal_pattern?(h) and literal_pattern?(t)
  defp literal_pattern?(_number_binary_pid_ref_fun), do: true

  defp uses_var?(var, var), do: true
  defp uses_var?(term, var) when is_tuple(term), do: term |> Tuple.to_list() |> uses_var?(var)
  defp uses_var?(term, var) when is_list(term), do: Enum.any?(term, &uses_var?(&1, var))
  defp uses_var?(term, var) when is_map(term), do: term |> Map.to_list() |> uses_var?(var)
  defp uses_var?(_term, _var), do: false
end
