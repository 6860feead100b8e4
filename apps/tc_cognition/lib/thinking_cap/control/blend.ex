defmodule ThinkingCap.Control.Blend do
  @moduledoc """
  Context-dependent blending of fuzzy behaviours (Saffiotti; the
  controller of ThinkingCap-II): each behaviour's fuzzy output sets are
  weighted by its **activation**, joined across behaviours, and the result
  is defuzzified **once**. Crisp outputs of behaviours are never averaged:
  two behaviours that disagree (one wants to turn, one to go straight on)
  would average into a command neither wants, such as driving into the
  obstacle one of them is avoiding.

  ## Activation

  A behaviour's activation is a context rule, `IF context THEN behaviour`,
  whose truth is the conjunction (minimum) of

    * its own context (`c:ThinkingCap.Control.Behaviour.context/2`);
    * its fixed `weight:` (default 1) and the plan's weight for it, if the
      inputs carry `weights: %{name => degree}` (default 1);
    * `NOT` each behaviour named in its `unless:` list, i.e.
      `1 - min(context, weights)` of that behaviour. This is how precedence
      is written, as in Saffiotti's context rules ("IF goal AND NOT
      obstacle THEN go-to"): a go-to `unless: [:avoid]` fades out as an
      obstacle gets near in the direction of travel and comes back as it
      clears. `unless:` names siblings in the same blend; it uses their
      context and weights, not their own `unless:` (no chains, no cycles).

  ## Weighting: clip, then join by maximum

  Each behaviour's set is clipped at its activation (minimum) and the
  clipped sets are joined by maximum, the same operators as the rules
  inside a behaviour (`ThinkingCap.Control.Fuzzy`): a blend is one more
  level of Mamdani rules, "IF context THEN the behaviour's set". Clipping
  rather than scaling because clipping is idempotent: a blend nested in a
  blend is clipped again at its own context (its largest activation),
  which changes nothing, so a composite gives the same command as the flat
  blend of its parts; scaling would multiply the activations at every
  level. And a behaviour's set keeps its shape: its preferred command (the
  peak) stays where it was, only its weight in the centroid changes.

  Each output variable is then defuzzified by its centroid. An empty set
  (no active behaviour has an opinion on that variable) gives `0.0`: with
  no opinion on speed, stop; on turning, do not turn.

  ## Ties

  The blend itself breaks no ties: two equally active behaviours wanting
  opposite turns defuzzify to straight on. Behaviours that choose between
  opposite turns do it themselves and deterministically
  (`ThinkingCap.Control.AvoidObstacles` turns to the freer side, ties to
  the left; `ThinkingCap.Control.GoToPoint` turns left for a goal exactly
  behind).

  ## Composite

  A blend is itself a `ThinkingCap.Control.Behaviour`: its context is its
  largest activation and its outputs are its joined (not defuzzified)
  sets, so a blend can be one behaviour of another blend.

      blend =
        Blend.init(behaviours: [
          {:avoid, AvoidObstacles, []},
          {:go_to, GoToPoint, [tolerance: 0.05], unless: [:avoid]}
        ])

      %{command: {v, w}, activations: %{avoid: a, go_to: g}} = Blend.run(blend, inputs)
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Fuzzy, Fuzzy.Set}

  defstruct entries: []

  @type entry :: %{
          name: atom(),
          module: module(),
          params: term(),
          weight: float(),
          unless: [atom()]
        }
  @type t :: %__MODULE__{entries: [entry()]}

  @typedoc "A behaviour of the blend: name, module, its `init/1` params and options (`weight:`, `unless:`)."
  @type spec :: {atom(), module(), keyword()} | {atom(), module(), keyword(), keyword()}

  @type result :: %{
          command: {float(), float()},
          activations: %{atom() => float()},
          outputs: %{v: Set.t(), w: Set.t()}
        }

  @doc """
  A blend of behaviours: `behaviours: [spec]` (`t:spec/0`). Each
  behaviour's params go through its module's `init/1`. Raises
  `ArgumentError` for duplicate names, an `unless:` naming no sibling or a
  weight outside [0, 1].
  """
  @impl true
  @spec init(keyword()) :: t()
  def init(params) do
    entries = params |> Keyword.get(:behaviours, []) |> Enum.map(&entry/1)
    names = Enum.map(entries, & &1.name)

    if length(Enum.uniq(names)) != length(names) do
      raise ArgumentError, "blend: duplicate behaviour names in #{inspect(names)}"
    end

    Enum.each(entries, fn e ->
      case e.unless -- names do
        [] ->
          :ok

        missing ->
          raise ArgumentError, "blend: #{e.name} unless: #{inspect(missing)}: no such behaviour"
      end
    end)

    %__MODULE__{entries: entries}
  end

  defp entry({name, module, params}), do: entry({name, module, params, []})

  defp entry({name, module, params, opts}) when is_atom(name) and is_atom(module) do
    weight = Keyword.get(opts, :weight, 1.0)

    unless is_number(weight) and weight >= 0 and weight <= 1 do
      raise ArgumentError,
            "blend: #{name} weight: expected a number in [0, 1], got #{inspect(weight)}"
    end

    %{
      name: name,
      module: module,
      params: module.init(params),
      weight: weight * 1.0,
      unless: Keyword.get(opts, :unless, [])
    }
  end

  defp entry(other) do
    raise ArgumentError,
          "blend: expected {name, module, params} or {name, module, params, opts}, got #{inspect(other)}"
  end

  @doc "The names of the blend's behaviours, in order."
  @spec names(t()) :: [atom()]
  def names(%__MODULE__{entries: entries}), do: Enum.map(entries, & &1.name)

  @doc """
  Blends the behaviours on the inputs: the crisp command `{v, w}` (m/s,
  rad/s), each behaviour's activation, and the joined output sets.
  """
  @spec run(t(), ThinkingCap.Control.Behaviour.inputs()) :: result()
  def run(blend, inputs) do
    {activations, outputs} = blend_sets(blend, inputs)
    v = Fuzzy.defuzzify(outputs.v, 0.0)
    w = Fuzzy.defuzzify(outputs.w, 0.0)
    %{command: {v, w}, activations: activations, outputs: outputs}
  end

  @impl true
  def evaluate(inputs, blend) do
    {activations, outputs} = blend_sets(blend, inputs)
    {activations |> Map.values() |> Enum.max(fn -> 0.0 end), outputs}
  end

  @impl true
  def context(inputs, blend), do: inputs |> evaluate(blend) |> elem(0)

  @impl true
  def outputs(inputs, blend), do: inputs |> evaluate(blend) |> elem(1)

  defp blend_sets(%__MODULE__{entries: entries}, inputs) do
    plan_weights = Map.get(inputs, :weights) || %{}

    evaluated =
      Map.new(entries, fn e ->
        {context, outputs} = ThinkingCap.Control.Behaviour.evaluate({e.module, e.params}, inputs)
        weighted = Enum.min([context, e.weight, Map.get(plan_weights, e.name, 1.0) * 1.0])
        {e.name, {weighted, outputs}}
      end)

    activations =
      Map.new(entries, fn e ->
        {weighted, _} = evaluated[e.name]

        inhibition =
          Enum.reduce(e.unless, 0.0, fn other, acc -> max(acc, elem(evaluated[other], 0)) end)

        {e.name, min(weighted, 1.0 - inhibition)}
      end)

    [v_var, w_var] = ThinkingCap.Control.Behaviour.output_variables(inputs.limits)

    outputs =
      Map.new([v: v_var, w: w_var], fn {var, %{universe: universe}} ->
        sets =
          Enum.flat_map(entries, fn e ->
            a = activations[e.name]

            case Map.get(elem(evaluated[e.name], 1), var) do
              %Set{} = set when a > 0.0 -> [Fuzzy.clip(set, a)]
              _ -> []
            end
          end)

        {var, Fuzzy.union([Fuzzy.empty_set(universe) | sets])}
      end)

    {activations, outputs}
  end
end
