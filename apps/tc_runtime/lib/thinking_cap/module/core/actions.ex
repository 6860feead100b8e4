defmodule ThinkingCap.Module.Core.Actions do
  @moduledoc false
  # The one reading of a module's callback results (`ThinkingCap.Module`):
  # checks what a callback returned and turns its actions into effects,
  # pure data the process hosting the module (`ThinkingCap.Runtime.Host`)
  # and the lockstep harness (`ThinkingCap.Testing.Lockstep`) carry out
  # each in its own way. Both call it, so they cannot read a module
  # differently.
  #
  # An effect is one of:
  #
  #   * `{:cycle_result, command | nil, wire | nil}` - first, from
  #     `handle_cycle/2` only: the cycle's result (the last `:command`,
  #     the last `:wire`; nil without one);
  #   * `{:out, tuple, opts}` - a blackboard write;
  #   * `{:subscribe, template}`;
  #   * `{:attach_wire, device, fallback_iodata}` and `:detach_wire`
  #     (periodic modules only: otherwise a `:warning`);
  #   * `{:set_param, key, value}` - the module sets one of its own params
  #     (checked against its schema by whoever carries it out);
  #   * `{:warning, message}` - an action that counts for nothing where it
  #     was given (a `:command` outside `handle_cycle/2`, say).
  #
  # A result that is not `{actions, state}`, or an action outside the
  # vocabulary (`ThinkingCap.Module.action/0`), is an error naming the
  # module and the callback (`ThinkingCap.Module.ActionError`).

  alias ThinkingCap.Module.ActionError

  @type callback ::
          :init
          | :handle_cycle
          | :handle_tuple
          | :handle_background
          | :handle_info
          | :handle_applied
          | :handle_param
          | :handle_swap

  @type activity :: :periodic | :event | :background

  @type effect ::
          {:cycle_result, term() | nil, iodata() | nil}
          | {:out, tuple(), keyword()}
          | {:subscribe, tuple()}
          | {:attach_wire, Path.t(), iodata()}
          | :detach_wire
          | {:set_param, atom(), term()}
          | {:warning, String.t()}

  @known "{:out, tuple}, {:out, {tuple, opts}}, {:command, term}, {:wire, iodata}, " <>
           "{:attach_wire, device, fallback_iodata}, {:detach_wire}, {:subscribe, template}, " <>
           "{:set_param, key, value}"

  @doc false
  # The documented vocabulary, for messages.
  def known, do: @known

  @doc false
  # Reads `result`, what `module`'s `callback` returned, for a module of
  # `activity`. `{:ok, effects, state}`, `{:refused, reason, state}` (from
  # `handle_param/3` only), or `{:error, %ActionError{}}`.
  @spec interpret(term(), module(), callback(), activity()) ::
          {:ok, [effect()], term()}
          | {:refused, String.t(), term()}
          | {:error, ActionError.t()}
  def interpret(result, module, callback, activity) do
    case result do
      {:ok, state} when callback in [:init, :handle_swap] ->
        {:ok, [], state}

      {:error, reason, state} when callback == :handle_param and is_binary(reason) ->
        {:refused, reason, state}

      {actions, state} when is_list(actions) ->
        effects(actions, module, callback, activity, state)

      other ->
        {:error,
         ActionError.exception(
           module: module,
           callback: callback,
           message:
             "#{signature(module, callback)} must return #{expected(callback)}, got: " <>
               inspect(other, limit: 10, printable_limit: 80)
         )}
    end
  end

  defp expected(:init), do: "{actions, state} or {:ok, state}"
  defp expected(:handle_swap), do: "{:ok, state}"
  defp expected(:handle_param), do: "{actions, state} or {:error, reason_string, state}"
  defp expected(_), do: "{actions, state}"

  defp effects(actions, module, callback, activity, state) do
    Enum.reduce_while(actions, {:ok, [], nil, nil}, fn action, {:ok, acc, command, wire} ->
      case effect(action, callback, activity) do
        {:command, c} -> {:cont, {:ok, acc, {c}, wire}}
        {:wire, w} -> {:cont, {:ok, acc, command, {w}}}
        {:ok, effect} -> {:cont, {:ok, [effect | acc], command, wire}}
        {:error, why} -> {:halt, {:error, error(module, callback, action, why)}}
      end
    end)
    |> case do
      {:ok, acc, command, wire} ->
        effects = Enum.reverse(acc)

        effects =
          if callback == :handle_cycle,
            do: [{:cycle_result, unwrap(command), unwrap(wire)} | effects],
            else: effects

        {:ok, effects, state}

      {:error, error} ->
        {:error, error}
    end
  end

  defp unwrap(nil), do: nil
  defp unwrap({x}), do: x

  # one action: its effect, or for :command and :wire in handle_cycle the
  # value the cycle's result takes, or why it is not an action
  defp effect(action, callback, activity) do
    case action do
      {:out, {tuple, opts}} when is_tuple(tuple) and is_list(opts) ->
        if Keyword.keyword?(opts),
          do: {:ok, {:out, tuple, opts}},
          else: {:error, "the options of :out are a keyword list"}

      {:out, tuple} when is_tuple(tuple) ->
        {:ok, {:out, tuple, []}}

      {:out, _} ->
        {:error, ":out takes a tuple, or {tuple, opts}"}

      {:command, command} when callback == :handle_cycle ->
        {:command, command}

      {:wire, wire} when callback == :handle_cycle ->
        if iodata?(wire), do: {:wire, wire}, else: {:error, ":wire takes iodata"}

      {kind, _} when kind in [:command, :wire] ->
        {:ok, {:warning, "a #{inspect(kind)} action only counts in handle_cycle/2"}}

      {:subscribe, template} when is_tuple(template) ->
        {:ok, {:subscribe, template}}

      {:subscribe, _} ->
        {:error, ":subscribe takes a template (a tuple)"}

      {:attach_wire, device, fallback} ->
        cond do
          not is_binary(device) ->
            {:error, ":attach_wire takes a device path (a string)"}

          not iodata?(fallback) ->
            {:error, ":attach_wire takes the fallback's bytes (iodata)"}

          activity != :periodic ->
            {:ok,
             {:warning, "an :attach_wire action (#{inspect(device)}) needs a periodic activity"}}

          true ->
            {:ok, {:attach_wire, device, fallback}}
        end

      {:detach_wire} ->
        if activity == :periodic,
          do: {:ok, :detach_wire},
          else: {:ok, {:warning, "a :detach_wire action needs a periodic activity"}}

      {:set_param, key, value} when is_atom(key) ->
        {:ok, {:set_param, key, value}}

      {:set_param, _, _} ->
        {:error, ":set_param takes an atom key"}

      {kind, _} when kind in [:attach_wire, :detach_wire, :set_param] ->
        {:error, "#{inspect(kind)} has the wrong number of elements"}

      _ ->
        {:error, :unknown}
    end
  end

  defp iodata?(x) when is_binary(x), do: true

  defp iodata?(x) when is_list(x) do
    IO.iodata_length(x)
    true
  rescue
    ArgumentError -> false
  end

  defp iodata?(_), do: false

  defp error(module, callback, action, :unknown) do
    ActionError.exception(
      module: module,
      callback: callback,
      action: action,
      message:
        "#{signature(module, callback)} returned an unknown action " <>
          "#{inspect(action, limit: 10, printable_limit: 80)}; known: #{@known}"
    )
  end

  defp error(module, callback, action, why) do
    ActionError.exception(
      module: module,
      callback: callback,
      action: action,
      message:
        "#{signature(module, callback)} returned a malformed action " <>
          "#{inspect(action, limit: 10, printable_limit: 80)}: #{why}"
    )
  end

  @arity %{
    init: 2,
    handle_cycle: 2,
    handle_tuple: 2,
    handle_background: 1,
    handle_info: 2,
    handle_applied: 2,
    handle_param: 3,
    handle_swap: 3
  }

  @doc false
  # `MyMod.handle_cycle/2`
  def signature(module, callback),
    do: "#{inspect(module)}.#{callback}/#{Map.get(@arity, callback, "?")}"
end
