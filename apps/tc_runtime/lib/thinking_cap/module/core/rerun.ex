defmodule ThinkingCap.Module.Core.Rerun do
  @moduledoc false
  # Runs a module's callbacks again on the inputs its trace gives
  # (ThinkingCap.Runtime.Trace), for a replay: no process, no blackboard,
  # no clock. Results are read by the runtime's own core (Core.Actions,
  # Core.Params), as the host reads them, and each callback's outcome is
  # given in the trace's terms (Trace.outputs/2), to be compared with the
  # recorded one.
  #
  # An input here is a traced input with its tuple found: `{:tuple, tuple}`
  # where the trace has `{:tuple, ref}`.

  alias ThinkingCap.Module.Core.{Actions, Params}
  alias ThinkingCap.Runtime.Trace

  defstruct [:name, :robot, :module, :activity, :state, :given, :params, :context]

  @type t :: %__MODULE__{}

  @typedoc "What a callback gave: its effects, a refused param change, or what it raised."
  @type outcome ::
          {:ok, [Actions.effect()]} | {:refused, String.t()} | {:raised, atom(), String.t()}

  # Starts module `name` as its trace's init event says. The rerun is nil
  # when init/2 raised.
  @spec init(atom(), map()) :: {t() | nil, outcome()}
  def init(name, %{module: module, params: params, context: context, activity: activity}) do
    rerun = %__MODULE__{
      name: name,
      robot: context.robot,
      module: module,
      activity: activity,
      given: params,
      params: Params.init(module, params),
      context: context
    }

    case guarded(fn -> interpret(module.init(params, context), module, :init, activity) end) do
      {:ok, effects, state} -> {own_params(%{rerun | state: state}, effects), {:ok, effects}}
      raised -> {nil, raised}
    end
  end

  # Runs one input through the module.
  @spec call(t(), tuple() | atom()) :: {t(), outcome()}
  def call(%__MODULE__{} = rerun, {:param, key, value}) do
    guarded(fn ->
      Params.set(rerun.params, rerun.module, rerun.state, key, value, rerun.activity, false)
    end)
    |> case do
      {:ok, _value, effects, state, params} ->
        {own_params(%{rerun | state: state, params: params}, effects), {:ok, effects}}

      {:error, message, state} ->
        {%{rerun | state: state}, {:refused, message}}

      {:crash, error} ->
        {rerun, {:raised, :error, banner(:error, error)}}

      {:raised, _kind, _message} = raised ->
        {rerun, raised}
    end
  end

  def call(%__MODULE__{} = rerun, {:swap, new_module}) do
    %{module: old, state: state, context: context, activity: activity} = rerun

    guarded(fn ->
      if Code.ensure_loaded?(new_module) and function_exported?(new_module, :handle_swap, 3),
        do:
          interpret(
            new_module.handle_swap(old, state, context),
            new_module,
            :handle_swap,
            activity
          ),
        else: interpret(new_module.init(rerun.given, context), new_module, :init, activity)
    end)
    |> case do
      {:ok, effects, state} ->
        # as the host: the new module's schema, the values set so far kept
        params = Params.init(new_module, rerun.given)
        kept = Map.take(rerun.params.values, Map.keys(params.values))
        params = %{params | values: Map.merge(params.values, kept)}
        {%{rerun | module: new_module, state: state, params: params}, {:ok, effects}}

      raised ->
        {rerun, raised}
    end
  end

  def call(%__MODULE__{module: module} = rerun, input) do
    {callback, args} = callback(input, rerun.state)

    case guarded(fn ->
           interpret(apply(module, callback, args), module, callback, rerun.activity)
         end) do
      {:ok, effects, state} -> {own_params(%{rerun | state: state}, effects), {:ok, effects}}
      raised -> {rerun, raised}
    end
  end

  defp callback({:tuple, tuple}, state), do: {:handle_tuple, [tuple, state]}
  defp callback({:cycle, release}, state), do: {:handle_cycle, [release, state]}
  defp callback({:applied, applied}, state), do: {:handle_applied, [applied, state]}
  defp callback(:background, state), do: {:handle_background, [state]}
  defp callback({:info, message}, state), do: {:handle_info, [message, state]}

  # The outcome as a trace has it (Trace.outputs/2).
  @spec traced(outcome(), atom()) :: Trace.outputs()
  def traced({:ok, effects}, robot), do: Trace.outputs(effects, robot)
  def traced(other, _robot), do: other

  # the module's own param changes, as the host keeps them
  defp own_params(rerun, effects) do
    Enum.reduce(effects, rerun, fn
      {:set_param, key, value}, rerun ->
        case Params.set(rerun.params, rerun.module, rerun.state, key, value, rerun.activity, true) do
          {:ok, _value, _effects, _state, params} -> %{rerun | params: params}
          _refused -> rerun
        end

      _effect, rerun ->
        rerun
    end)
  end

  defp interpret(result, module, callback, activity) do
    case Actions.interpret(result, module, callback, activity) do
      {:ok, effects, state} -> {:ok, effects, state}
      {:error, error} -> raise error
    end
  end

  defp guarded(fun) do
    fun.()
  catch
    kind, reason -> {:raised, kind, banner(kind, reason)}
  end

  # as the host traces it
  defp banner(kind, reason),
    do: kind |> Exception.format_banner(reason) |> String.slice(0, 500)
end
