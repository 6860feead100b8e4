defmodule ThinkingCap.Module.Core.Params do
  @moduledoc false
  # A running module's params, and the one reading of a change to them
  # (live parameters, `ThinkingCap.Module`): pure, shared by the process
  # hosting a module (`ThinkingCap.Runtime.Host`) and the lockstep harness
  # (`ThinkingCap.Testing.Lockstep`).
  #
  # A change is checked against the schema the module declares
  # (`params/0`): the key must be one of its fields, not `read_only`, the
  # module must take live changes (`handle_param/3`), and the value must
  # be of the field's type (the message says the range, the type). Then
  # the module's `handle_param/3` sees it and may still refuse it
  # (`{:error, reason, state}`); accepted, it is the param's new value,
  # written to the blackboard as `record/5` says.

  alias ThinkingCap.Config.{ADF, Schema}
  alias ThinkingCap.Module.Core.Actions
  alias ThinkingCap.Tuples
  require Tuples

  @type t :: %{schema: Schema.fields() | nil, values: map(), live: boolean()}

  @doc false
  # The params of `module` started with `given` (the ADF's): the declared
  # fields with their defaults filled in, or what was given as a map.
  @spec init(module(), keyword() | map() | nil) :: t()
  def init(module, given) do
    given = if is_map(given), do: Map.to_list(given), else: given || []
    schema = ADF.declared_params(module)

    values =
      cond do
        schema != nil and Keyword.keyword?(given) ->
          {values, _errors} = Schema.validate(given, {:keyword, schema}, "params", %{})
          # keys the schema does not know (the ADF reader refused them)
          Map.merge(Map.new(given), values)

        Keyword.keyword?(given) ->
          Map.new(given)

        true ->
          %{}
      end

    %{schema: schema, values: values, live: function_exported?(module, :handle_param, 3)}
  end

  @doc false
  # Checks a change of `key` to `value` asked from outside the module:
  # the value as the module will see it (numbers of a number type as
  # floats), or why not.
  @spec check(t(), module(), atom(), term()) :: {:ok, term()} | {:error, String.t()}
  def check(%{schema: nil}, module, _key, _value),
    do:
      {:error,
       "#{inspect(module)} declares no params (params/0), so none can be set while it runs"}

  def check(params, module, key, value) do
    with {:ok, {type, opts}} <- field(params, module, key) do
      cond do
        opts[:read_only] ->
          {:error,
           "#{key} of #{inspect(module)} is read-only: it is set in the ADF and read when the module starts"}

        not params.live ->
          {:error,
           "#{inspect(module)} takes no live changes of its params (it has no handle_param/3): " <>
             "#{key} is set in the ADF"}

        true ->
          validate(type, key, value)
      end
    end
  end

  @doc false
  # A change the module asks for itself (a `{:set_param, key, value}`
  # action): the key must be declared and the value of its type.
  @spec check_own(t(), module(), atom(), term()) :: {:ok, term()} | {:error, String.t()}
  def check_own(%{schema: nil}, module, key, _value),
    do: {:error, "#{inspect(module)} declares no params (params/0): cannot set #{key}"}

  def check_own(params, module, key, value) do
    with {:ok, {type, _opts}} <- field(params, module, key), do: validate(type, key, value)
  end

  defp field(params, module, key) do
    case is_atom(key) && List.keyfind(params.schema, key, 0) do
      {^key, field} ->
        {:ok, field}

      _ ->
        known = Keyword.keys(params.schema)

        {:error,
         "#{inspect(module)} has no param #{inspect(key)}#{did_you_mean(key, known)}; " <>
           "its params: #{Enum.map_join(known, ", ", &inspect/1)}"}
    end
  end

  defp validate(type, key, value) do
    st = %{file: "", positions: %{}, errors: []}

    case Schema.check_at(st, type, value, [key]) do
      {value, %{errors: []}} -> {:ok, value}
      {_value, st} -> {:error, st |> Schema.errors() |> Enum.map_join("; ", & &1.message)}
    end
  rescue
    # an integer too large to be a float, given where a number is asked
    ArithmeticError -> {:error, "#{key}: #{inspect(value, limit: 3)} is too large a number"}
  end

  defp did_you_mean(key, known) do
    key = to_string(key)
    best = Enum.max_by(known, &String.jaro_distance(to_string(&1), key), fn -> nil end)

    if best != nil and String.jaro_distance(to_string(best), key) >= 0.8,
      do: "; did you mean #{inspect(best)}?",
      else: ""
  end

  @doc false
  # Asks `module` (in `mstate`) to take `key` = `value`, checked
  # (`check/4`, or `check_own/4` when `own`): `{:ok, value, effects,
  # mstate, params}` when it took it, `{:error, message, mstate}` when it
  # was refused (by the schema or by the module), `{:crash, ActionError}`
  # when handle_param/3 returned what cannot be read.
  @spec set(t(), module(), term(), atom(), term(), Actions.activity(), boolean()) ::
          {:ok, term(), [Actions.effect()], term(), t()}
          | {:error, String.t(), term()}
          | {:crash, Exception.t()}
  def set(params, module, mstate, key, value, activity, own \\ false) do
    checked =
      if own, do: check_own(params, module, key, value), else: check(params, module, key, value)

    with {:ok, value} <- checked do
      if own do
        {:ok, value, [], mstate, put(params, key, value)}
      else
        module.handle_param(key, value, mstate)
        |> Actions.interpret(module, :handle_param, activity)
        |> case do
          {:ok, effects, mstate} ->
            {:ok, value, effects, mstate, put(params, key, value)}

          # a refusal leaves the module's state as it was
          {:refused, reason, _} ->
            {:error, "#{inspect(module)} refused #{key}: #{reason}", mstate}

          {:error, error} ->
            {:crash, error}
        end
      end
    else
      {:error, message} -> {:error, message, mstate}
    end
  end

  defp put(params, key, value), do: %{params | values: Map.put(params.values, key, value)}

  @doc false
  # The blackboard write recording an accepted change: the latest per
  # robot, module and key.
  @spec record(atom(), atom(), atom(), term(), term()) :: {tuple(), keyword()}
  def record(robot, name, key, value, by) do
    Tuples.keyed(
      Tuples.param(
        robot,
        %{module: name, key: key, value: value, by: by, at: System.os_time(:millisecond)}
      )
    )
  end

  @doc false
  # The params as a user interface shows them: each field with its kind
  # of input (`:number`, `:integer`, `:boolean`, `:choice`, `:string` or
  # `:other`, not editable), its bounds or choices, whether it is
  # read-only (declared so, or the module takes no live changes), its
  # doc, default and current value.
  @spec describe(t()) :: [map()]
  def describe(%{schema: nil}), do: []

  def describe(params) do
    for {key, {type, opts}} <- params.schema do
      Map.merge(
        %{
          key: key,
          type: Schema.type_name(type),
          read_only: opts[:read_only] == true or not params.live,
          doc: opts[:doc],
          default: opts[:default],
          value: Map.get(params.values, key)
        },
        input(type)
      )
    end
  end

  defp input({:number_range, min, max}), do: %{input: :number, min: min, max: max}
  defp input({:int_range, min, max}), do: %{input: :integer, min: min, max: max}
  defp input(:port), do: %{input: :integer, min: 1, max: 65_535}
  defp input(:number), do: %{input: :number}
  defp input(:pos_number), do: %{input: :number, min: 0, exclusive_min: true}
  defp input(:non_neg_number), do: %{input: :number, min: 0}
  defp input(:probability), do: %{input: :number, min: 0, max: 1}
  defp input(:integer), do: %{input: :integer}
  defp input(:pos_integer), do: %{input: :integer, min: 1}
  defp input(:non_neg_integer), do: %{input: :integer, min: 0}
  defp input(:boolean), do: %{input: :boolean}
  defp input(:string), do: %{input: :string}

  defp input({:one_of, values}) do
    if Enum.all?(values, &(is_atom(&1) or is_binary(&1) or is_number(&1))),
      do: %{input: :choice, choices: values},
      else: %{input: :other}
  end

  defp input(_type), do: %{input: :other}
end
