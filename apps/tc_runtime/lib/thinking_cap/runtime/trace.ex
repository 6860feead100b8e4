defmodule ThinkingCap.Runtime.Trace do
  @moduledoc """
  What each hosted module received and returned, callback by callback:
  the runtime's side of a replay (`ThinkingCap.Testing.Replay`, `mix
  tc.replay`). A module's outputs depend on its params and context, on
  the tuples it was delivered and in which order, on its releases (their
  times), on the commands applied for it and on live param changes. The
  host of every module sends all of these, as they happen, to the
  processes attached to its robot (the recorder,
  `ThinkingCap.BlackBox.Recorder`), with what the callback returned.

      :ok = Trace.attach(:r1)
      # {:tc_trace, :r1, :control, 0, {{:init, info}, outputs}}
      # {:tc_trace, :r1, :control, 1, {{:tuple, {:hash, :lps, 12345678}}, []}}

  Nothing is traced while no process is attached: a host looks its
  robot's sinks up (a `:pg` group) at each callback. A sink may be on
  another node; a message the link cannot take at once is dropped, and
  the gap shows in the numbers.

  A sink that takes every callback of many modules (the recorder) can
  ask for them in lists (`attach(robot, batch: true)`): each host then
  holds its module's events and sends them as `{:tc_trace_batch, robot,
  name, [{n, at, event}]}`, oldest first, when it holds 64, or
  100 ms after the first (`max_delay_ms:` sets that delay for the
  robot's hosts; the last batched attach of a robot sets it) (`at` is `System.monotonic_time/0` when the
  callback ended, when the event would have been sent). A module's
  lists come in its order; a host that stops sends what it holds first,
  but one that is killed loses it (the numbers show the gap).

  ## Events

  A sink gets `{:tc_trace, robot, name, n, {input, outputs}}` for each
  callback of module `name`, in the order the module ran them; `n`
  counts the callbacks since its `init/2` (0), so a recording that began
  later, or lost an event, shows it. Inputs:

  | input | callback |
  |---|---|
  | `{:init, %{module:, params:, context:, activity:, period:, node:}}` | `init/2` (the ADF's params as given, the context) |
  | `{:tuple, ref}` | `handle_tuple/2` (`ref/2`) |
  | `{:cycle, release}` | `handle_cycle/2` |
  | `{:applied, applied}` | `handle_applied/2` |
  | `{:param, key, value}` | a live change asked from outside (`handle_param/3`) |
  | `:background` | `handle_background/1` |
  | `{:info, message}` | `handle_info/2` |
  | `{:swap, module}` | a swap: the new module's `handle_swap/3` or `init/2` |

  Outputs are the callback's effects as the runtime read them
  (`output/2` each), or `{:refused, message}` for a param change that was
  refused, or `{:raised, kind, message}` when the callback raised.

  A tuple is named by `ref/2`: the robot's own tuples (`{tag, robot,
  payload}`, which its recorder keeps whole) by their tag and a hash of
  the whole term, others whole.

  ## Not traced

  A module whose `c:ThinkingCap.Module.replay/0` says `trace: false`: a
  robot's driver (`use ThinkingCap.Robot` says so), whose inputs are its
  hardware and whose outputs are what the robot sensed.
  """

  alias ThinkingCap.Module.Core.Actions

  @typedoc "A tuple named in a trace: by tag and hash, or whole."
  @type ref :: {:hash, term(), non_neg_integer()} | {:term, tuple()}

  @typedoc "One callback's input (see the moduledoc)."
  @type input ::
          {:init, map()}
          | {:tuple, ref()}
          | {:cycle, map()}
          | {:applied, map()}
          | {:param, atom(), term()}
          | :background
          | {:info, term()}
          | {:swap, module()}

  @typedoc "One effect as traced: tuples written named by `ref/2`, a wire by its hash."
  @type output ::
          {:cycle_result, term(), non_neg_integer() | nil}
          | {:out, ref(), keyword()}
          | Actions.effect()

  @typedoc "What a callback gave."
  @type outputs :: [output()] | {:refused, String.t()} | {:raised, atom(), String.t()}

  @typedoc "One traced callback."
  @type event :: {input(), outputs()}

  # phash2's widest range
  @range 4_294_967_296

  # a host's events held for the batched sinks: so many, or so long
  @max_batch 64
  @max_delay_ms 100

  @doc """
  Makes the calling process a sink of `robot`'s trace; with `batch: true`
  its events come in lists (see the moduledoc), held up to
  `max_delay_ms` (default #{@max_delay_ms}) after the first.
  """
  @spec attach(atom(), [{:batch, boolean()} | {:max_delay_ms, pos_integer()}]) :: :ok
  def attach(robot, opts \\ [])

  def attach(robot, opts) when is_atom(robot) and is_list(opts) do
    {batch, delay} =
      case opts do
        [] ->
          {false, nil}

        [batch: batch] when is_boolean(batch) ->
          {batch, @max_delay_ms}

        [batch: true, max_delay_ms: ms] when is_integer(ms) and ms > 0 ->
          {true, ms}

        _ ->
          raise ArgumentError,
                "Trace.attach/2 takes [batch: boolean] or [batch: true, max_delay_ms: " <>
                  "positive integer], got: #{inspect(opts)}"
      end

    if batch, do: put_delay(robot, delay)
    :pg.join(ThinkingCap.Runtime.scope(), group(robot, batch), self())
  end

  # a robot's hold, read by its hosts at each event: written only when it
  # changes (a persistent term's update is costly, its read is not)
  defp put_delay(robot, delay) do
    key = {__MODULE__, :delay, robot}

    if :persistent_term.get(key, @max_delay_ms) != delay,
      do: :persistent_term.put(key, delay)
  end

  @doc "The calling process stops being a sink of `robot`'s trace."
  @spec detach(atom()) :: :ok
  def detach(robot) when is_atom(robot) do
    _ = :pg.leave(ThinkingCap.Runtime.scope(), group(robot, false), self())
    _ = :pg.leave(ThinkingCap.Runtime.scope(), group(robot, true), self())
    # the robot's hold, once no batched sink is left
    if batch_sinks(robot) == [], do: :persistent_term.erase({__MODULE__, :delay, robot})
    :ok
  end

  @doc "The processes attached to `robot`'s trace, on every node, batched or not."
  @spec sinks(atom()) :: [pid()]
  def sinks(robot), do: plain_sinks(robot) ++ batch_sinks(robot)

  @doc false
  # the sinks sent each event as it comes
  @spec plain_sinks(atom()) :: [pid()]
  def plain_sinks(robot), do: :pg.get_members(ThinkingCap.Runtime.scope(), group(robot, false))

  @doc false
  # the sinks sent lists
  @spec batch_sinks(atom()) :: [pid()]
  def batch_sinks(robot), do: :pg.get_members(ThinkingCap.Runtime.scope(), group(robot, true))

  defp group(robot, false), do: {:tc_trace, robot}
  defp group(robot, true), do: {:tc_trace_batch, robot}

  @doc false
  # how many events a host of `robot` holds for the batched sinks, and how long
  @spec batching(atom()) :: {pos_integer(), pos_integer()}
  def batching(robot),
    do: {@max_batch, :persistent_term.get({__MODULE__, :delay, robot}, @max_delay_ms)}

  @doc """
  Whether a module's callbacks are traced: unless its
  `c:ThinkingCap.Module.replay/0` says `trace: false`.
  """
  @spec traced?(module()) :: boolean()
  def traced?(module), do: Keyword.get(replay_options(module), :trace, true) != false

  @doc """
  The parts of a module's outputs that measure the machine it ran on
  (`c:ThinkingCap.Module.replay/0`'s `measurements:`), `[{tag, path}]`.
  """
  @spec measurements(module()) :: [{atom(), [term()]}]
  def measurements(module), do: Keyword.get(replay_options(module), :measurements, [])

  defp replay_options(module) do
    if Code.ensure_loaded?(module) and function_exported?(module, :replay, 0) do
      case module.replay() do
        opts when is_list(opts) -> opts
        _ -> []
      end
    else
      []
    end
  end

  @doc """
  A tuple as a trace names it: `{:hash, tag, hash}` for a tuple of
  `robot` (`{tag, robot, payload}`: its recorder keeps it), else
  `{:term, tuple}`.
  """
  @spec ref(tuple(), atom()) :: ref()
  def ref({tag, robot, _payload} = tuple, robot), do: {:hash, tag, hash(tuple)}
  def ref(tuple, _robot), do: {:term, tuple}

  @doc "The hash `ref/2` gives a term (`:erlang.phash2/2`, 32 bits)."
  @spec hash(term()) :: non_neg_integer()
  def hash(term), do: :erlang.phash2(term, @range)

  @doc "A callback's input as traced (`callback` a `ThinkingCap.Module` callback's name, `args` its arguments)."
  @spec input(atom(), list(), atom()) :: input()
  def input(:handle_tuple, [tuple, _state], robot), do: {:tuple, ref(tuple, robot)}
  def input(:handle_cycle, [release, _state], _robot), do: {:cycle, release}
  def input(:handle_applied, [applied, _state], _robot), do: {:applied, applied}
  def input(:handle_background, [_state], _robot), do: :background
  def input(:handle_info, [message, _state], _robot), do: {:info, message}

  @doc "An effect as traced (see `t:output/0`)."
  @spec output(Actions.effect(), atom()) :: output()
  def output({:out, tuple, opts}, robot), do: {:out, ref(tuple, robot), opts}
  def output({:cycle_result, command, nil}, _robot), do: {:cycle_result, command, nil}
  def output({:cycle_result, command, wire}, _robot), do: {:cycle_result, command, hash(wire)}
  def output(effect, _robot), do: effect

  @doc "Every effect as traced."
  @spec outputs([Actions.effect()], atom()) :: [output()]
  def outputs(effects, robot), do: Enum.map(effects, &output(&1, robot))

  @doc false
  # Sends one event to the sinks; never blocks on a busy link.
  @spec send([pid()], atom(), atom(), non_neg_integer(), event()) :: :ok
  def send(sinks, robot, name, n, event) do
    message = {:tc_trace, robot, name, n, event}
    Enum.each(sinks, &:erlang.send(&1, message, [:noconnect, :nosuspend]))
  end

  @doc false
  # Sends a list of one module's events, `[{n, at, event}]` oldest first,
  # to the batched sinks; never blocks on a busy link.
  @spec send_batch([pid()], atom(), atom(), [{non_neg_integer(), integer(), event()}]) :: :ok
  def send_batch(sinks, robot, name, events) do
    message = {:tc_trace_batch, robot, name, events}
    Enum.each(sinks, &:erlang.send(&1, message, [:noconnect, :nosuspend]))
  end
end
