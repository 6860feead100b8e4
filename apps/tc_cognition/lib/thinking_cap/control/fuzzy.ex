defmodule ThinkingCap.Control.Fuzzy do
  @moduledoc """
  A small Mamdani fuzzy engine whose rule bases are plain data.

  ## Membership functions

  A membership function is a tuple (all parameters in the variable's
  units, in non-decreasing order):

    * `{:triangle, a, b, c}` - 0 outside `[a, c]`, 1 at `b`, linear between;
    * `{:trapezoid, a, b, c, d}` - 0 outside `[a, d]`, 1 on `[b, c]`,
      linear between (`a == b` or `c == d` give vertical sides);
    * `{:left_shoulder, a, b}` - 1 up to `a`, falling linearly to 0 at `b`
      and 0 beyond ("small");
    * `{:right_shoulder, a, b}` - 0 up to `a`, rising linearly to 1 at `b`
      and 1 beyond ("large");
    * `{:singleton, x0}` - 1 at exactly `x0`, 0 elsewhere. In an output
      variable's sampled set it takes the sample nearest `x0` (so it never
      falls between samples).

  ## Variables

  A linguistic variable (`variable/3`) has a name, a universe `{min, max}`
  and a map of terms to membership functions. Crisp inputs are clamped to
  their universe before they are fuzzified.

  ## Rule bases

  A rule base is a list of rules; a rule is a keyword list:

      [if: condition, then: [output_variable: term, ...]]
      [if: condition, then: [...], weight: 0.5]

  and a condition is one of

    * `{:is, variable, term}` - the input variable's degree in the term;
    * `{:and, [condition, ...]}` - minimum (an empty list is `true`);
    * `{:or, [condition, ...]}` - maximum (an empty list is `false`);
    * `{:not, condition}` - `1 - x`;
    * `true` / `false` - 1 / 0 (an unconditional rule).

  For example

      [
        [if: {:is, :front, :near}, then: [speed: :slow]],
        [if: {:and, [{:is, :front, :near}, {:not, {:is, :left, :near}}]}, then: [turn: :left]],
        [if: {:is, :front, :far}, then: [speed: :fast, turn: :straight], weight: 0.5]
      ]

  A rule fires with the degree of its condition times its `weight`
  (default 1). Each conclusion clips its term's membership function at that
  degree (implication by minimum) and the clipped sets of all rules are
  joined by maximum (aggregation). Output sets are sampled on `samples`
  (default 101) evenly spaced points of the output universe, ends included
  (`ThinkingCap.Control.Fuzzy.Set`).

  ## Defuzzification

  `defuzzify/2` gives the centroid `Σ xᵢ μᵢ / Σ μᵢ` of the samples. An
  empty set (every degree 0: no rule fired) has no centroid: `defuzzify/2`
  then returns its `empty` argument (`nil` by default), so the caller says
  what "no opinion" means (the controller stops).
  """

  alias ThinkingCap.Control.Fuzzy.{Set, Variable}

  @type membership ::
          {:triangle, number(), number(), number()}
          | {:trapezoid, number(), number(), number(), number()}
          | {:left_shoulder, number(), number()}
          | {:right_shoulder, number(), number()}
          | {:singleton, number()}

  @type condition ::
          {:is, atom(), atom()}
          | {:and, [condition()]}
          | {:or, [condition()]}
          | {:not, condition()}
          | boolean()

  @type rule :: [if: condition(), then: [{atom(), atom()}], weight: number()]
  @type rule_base :: [rule()]
  @type variables :: [Variable.t()] | %{atom() => Variable.t()}

  @default_samples 101

  @doc """
  A linguistic variable. Raises `ArgumentError` for an empty universe or a
  membership function that is malformed or whose points are out of order.
  """
  @spec variable(atom(), {number(), number()}, %{atom() => membership()} | keyword()) ::
          Variable.t()
  def variable(name, {lo, hi}, terms) when is_atom(name) and is_number(lo) and is_number(hi) do
    if lo >= hi, do: raise(ArgumentError, "#{inspect(name)}: empty universe {#{lo}, #{hi}}")

    terms =
      Map.new(terms, fn {term, mf} ->
        check_membership!(name, term, mf)
        {term, mf}
      end)

    %Variable{name: name, universe: {lo * 1.0, hi * 1.0}, terms: terms}
  end

  defp check_membership!(name, term, mf) do
    points =
      case mf do
        {:triangle, a, b, c} -> [a, b, c]
        {:trapezoid, a, b, c, d} -> [a, b, c, d]
        {:left_shoulder, a, b} -> [a, b]
        {:right_shoulder, a, b} -> [a, b]
        {:singleton, x} -> [x]
        _ -> nil
      end

    cond do
      points == nil or not Enum.all?(points, &is_number/1) ->
        raise ArgumentError, "#{inspect(name)}.#{term}: not a membership function: #{inspect(mf)}"

      points != Enum.sort(points) ->
        raise ArgumentError, "#{inspect(name)}.#{term}: points out of order: #{inspect(mf)}"

      true ->
        :ok
    end
  end

  @doc "The degree of `x` in a membership function."
  @spec membership(membership(), number()) :: float()
  def membership({:triangle, a, b, c}, x), do: membership({:trapezoid, a, b, b, c}, x)

  def membership({:trapezoid, a, b, c, d}, x) do
    cond do
      x < a or x > d -> 0.0
      x < b -> (x - a) / (b - a)
      x <= c -> 1.0
      true -> (d - x) / (d - c)
    end
  end

  def membership({:left_shoulder, a, b}, x) do
    cond do
      x <= a -> 1.0
      x >= b -> 0.0
      true -> (b - x) / (b - a)
    end
  end

  def membership({:right_shoulder, a, b}, x) do
    cond do
      x <= a -> 0.0
      x >= b -> 1.0
      true -> (x - a) / (b - a)
    end
  end

  def membership({:singleton, x0}, x), do: if(x == x0, do: 1.0, else: 0.0)

  @doc """
  The degree of truth of a condition given crisp inputs (`%{name => number}`)
  and the variables they belong to. Raises `ArgumentError` naming an unknown
  variable or term or a missing input.
  """
  @spec truth(condition(), %{atom() => number()}, variables()) :: float()
  def truth(condition, inputs, variables), do: degree(condition, inputs, by_name(variables))

  defp degree(true, _inputs, _vars), do: 1.0
  defp degree(false, _inputs, _vars), do: 0.0

  defp degree({:is, name, term}, inputs, vars) do
    var = fetch_variable!(vars, name)
    mf = fetch_term!(var, term)

    case inputs do
      %{^name => x} when is_number(x) ->
        {lo, hi} = var.universe
        membership(mf, x |> max(lo) |> min(hi))

      _ ->
        raise ArgumentError, "no crisp input for #{inspect(name)}"
    end
  end

  defp degree({:and, conditions}, inputs, vars) when is_list(conditions),
    do: Enum.reduce(conditions, 1.0, &min(&2, degree(&1, inputs, vars)))

  defp degree({:or, conditions}, inputs, vars) when is_list(conditions),
    do: Enum.reduce(conditions, 0.0, &max(&2, degree(&1, inputs, vars)))

  defp degree({:not, condition}, inputs, vars), do: 1.0 - degree(condition, inputs, vars)

  defp degree(other, _inputs, _vars),
    do: raise(ArgumentError, "not a condition: #{inspect(other)}")

  @doc """
  Evaluates a rule base on crisp inputs: a fuzzy set for every output
  variable named in a conclusion (an empty set when none of its rules
  fired). `variables` holds the input and output variables; `opts`:
  `samples:` (default #{@default_samples}).

      iex> alias ThinkingCap.Control.Fuzzy
      iex> vars = [
      ...>   Fuzzy.variable(:x, {0, 1}, small: {:left_shoulder, 0, 1}),
      ...>   Fuzzy.variable(:y, {0, 10}, low: {:triangle, 0, 2, 4})
      ...> ]
      iex> %{y: set} = Fuzzy.evaluate([[if: {:is, :x, :small}, then: [y: :low]]], %{x: 0.5}, vars)
      iex> Fuzzy.defuzzify(set)
      2.0
  """
  @spec evaluate(rule_base(), %{atom() => number()}, variables(), keyword()) :: %{
          atom() => Set.t()
        }
  def evaluate(rules, inputs, variables, opts \\ []) when is_list(rules) do
    vars = by_name(variables)
    samples = Keyword.get(opts, :samples, @default_samples)

    strengths =
      Enum.reduce(rules, %{}, fn rule, acc ->
        {condition, conclusions, weight} = parse_rule!(rule)
        alpha = degree(condition, inputs, vars) * weight

        Enum.reduce(conclusions, acc, fn {output, term}, acc ->
          fetch_term!(fetch_variable!(vars, output), term)
          terms = Map.get(acc, output, %{})
          Map.put(acc, output, Map.update(terms, term, alpha, &max(&1, alpha)))
        end)
      end)

    Map.new(strengths, fn {output, terms} ->
      {output, sample(Map.fetch!(vars, output), terms, samples)}
    end)
  end

  defp parse_rule!(rule) when is_list(rule) do
    with {:ok, condition} <- Keyword.fetch(rule, :if),
         {:ok, [_ | _] = conclusions} <- Keyword.fetch(rule, :then),
         true <- Keyword.keyword?(conclusions),
         weight when is_number(weight) and weight >= 0 and weight <= 1 <-
           Keyword.get(rule, :weight, 1.0) do
      {condition, conclusions, weight * 1.0}
    else
      _ -> bad_rule!(rule)
    end
  end

  defp parse_rule!(rule), do: bad_rule!(rule)

  defp bad_rule!(rule) do
    raise ArgumentError,
          "not a rule (expected [if: condition, then: [variable: term, ...]] " <>
            "and an optional weight: in [0, 1]): #{inspect(rule)}"
  end

  @doc """
  Checks a rule base against its variables without evaluating it: `:ok`, or
  `{:error, message}` naming the first malformed rule, unknown variable or
  unknown term.
  """
  @spec validate(rule_base(), variables()) :: :ok | {:error, String.t()}
  def validate(rules, variables) do
    vars = by_name(variables)

    Enum.each(rules, fn rule ->
      {condition, conclusions, _weight} = parse_rule!(rule)
      check_condition!(condition, vars)
      Enum.each(conclusions, fn {out, term} -> fetch_term!(fetch_variable!(vars, out), term) end)
    end)
  rescue
    e in ArgumentError -> {:error, Exception.message(e)}
  end

  defp check_condition!(bool, _vars) when is_boolean(bool), do: :ok

  defp check_condition!({:is, name, term}, vars),
    do: fetch_term!(fetch_variable!(vars, name), term)

  defp check_condition!({op, list}, vars) when op in [:and, :or] and is_list(list),
    do: Enum.each(list, &check_condition!(&1, vars))

  defp check_condition!({:not, c}, vars), do: check_condition!(c, vars)

  defp check_condition!(other, _vars),
    do: raise(ArgumentError, "not a condition: #{inspect(other)}")

  # aggregated set of one output: max over terms of min(alpha, mf(x))
  defp sample(%Variable{universe: {lo, hi}} = var, terms, n) do
    fired = for {term, alpha} <- terms, alpha > 0.0, do: {Map.fetch!(var.terms, term), alpha}
    step = (hi - lo) / (n - 1)

    degrees =
      for i <- 0..(n - 1) do
        x = lo + i * step

        Enum.reduce(fired, 0.0, fn {mf, alpha}, acc ->
          max(acc, min(alpha, sampled_membership(mf, x, step)))
        end)
      end

    %Set{universe: {lo, hi}, degrees: List.to_tuple(degrees)}
  end

  # a singleton belongs to its nearest sample
  defp sampled_membership({:singleton, x0}, x, step),
    do: if(abs(x - x0) < step / 2 or (abs(x - x0) == step / 2 and x < x0), do: 1.0, else: 0.0)

  defp sampled_membership(mf, x, _step), do: membership(mf, x)

  @doc "An empty output set over a universe (every degree 0)."
  @spec empty_set({number(), number()}, pos_integer()) :: Set.t()
  def empty_set({lo, hi}, samples \\ @default_samples) when samples >= 2,
    do: %Set{universe: {lo * 1.0, hi * 1.0}, degrees: Tuple.duplicate(0.0, samples)}

  @doc "A set clipped at `degree` (implication by minimum)."
  @spec clip(Set.t(), number()) :: Set.t()
  def clip(%Set{degrees: degrees} = set, degree) do
    clipped = degrees |> Tuple.to_list() |> Enum.map(&min(&1, degree)) |> List.to_tuple()
    %{set | degrees: clipped}
  end

  @doc """
  The union (maximum) of sets over the same universe and samples. Raises
  `ArgumentError` when their universes or sample counts differ, or when
  given no sets.
  """
  @spec union([Set.t()]) :: Set.t()
  def union([first | rest]) do
    Enum.reduce(rest, first, fn set, acc ->
      if set.universe != acc.universe or tuple_size(set.degrees) != tuple_size(acc.degrees) do
        raise ArgumentError,
              "cannot join sets over #{inspect(acc.universe)}/#{tuple_size(acc.degrees)} " <>
                "and #{inspect(set.universe)}/#{tuple_size(set.degrees)} samples"
      end

      degrees = Enum.zip_with(Tuple.to_list(acc.degrees), Tuple.to_list(set.degrees), &max/2)

      %{acc | degrees: List.to_tuple(degrees)}
    end)
  end

  def union([]), do: raise(ArgumentError, "the union of no sets has no universe")

  @doc "The height of a set (its largest degree): 0 for an empty set."
  @spec height(Set.t()) :: float()
  def height(%Set{degrees: degrees}), do: degrees |> Tuple.to_list() |> Enum.max()

  @doc """
  The centroid of a set, `Σ xᵢ μᵢ / Σ μᵢ` over its samples; `empty` (default
  `nil`) when every degree is 0.
  """
  @spec defuzzify(Set.t(), term()) :: float() | term()
  def defuzzify(%Set{universe: {lo, hi}, degrees: degrees}, empty \\ nil) do
    n = tuple_size(degrees)
    step = (hi - lo) / (n - 1)

    {moment, area} =
      Enum.reduce(0..(n - 1), {0.0, 0.0}, fn i, {m, a} ->
        mu = elem(degrees, i)
        {m + (lo + i * step) * mu, a + mu}
      end)

    if area > 0.0, do: moment / area, else: empty
  end

  defp by_name(variables) when is_map(variables), do: variables
  defp by_name(variables) when is_list(variables), do: Map.new(variables, &{&1.name, &1})

  defp fetch_variable!(vars, name) do
    case vars do
      %{^name => var} -> var
      _ -> raise ArgumentError, "unknown variable #{inspect(name)}"
    end
  end

  defp fetch_term!(%Variable{terms: terms, name: name}, term) do
    case terms do
      %{^term => mf} -> mf
      _ -> raise ArgumentError, "unknown term #{inspect(term)} of #{inspect(name)}"
    end
  end
end
