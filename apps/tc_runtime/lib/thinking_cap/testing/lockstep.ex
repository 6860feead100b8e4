defmodule ThinkingCap.Testing.Lockstep do
  @moduledoc """
  Runs a set of modules (`ThinkingCap.Module`) in lockstep with a
  simulated clock, in the calling process, without the runtime: a private
  blackboard, subscriptions honoured, periodic modules released when the
  simulated time reaches their next release. Deterministic and as fast as
  the modules themselves: for tests and benchmarks of whole cognitive
  stacks (a simulator in `:fast` mode feeds it the readings).

      lock =
        Lockstep.new(robot: :r1, rdf: rdf, wdf: wdf, modules: [
          perception: {ThinkingCap.Perception.Fuser, []},
          control: {ThinkingCap.Control.Blender, [], period: 0.1}
        ])

      lock = Lockstep.deliver(lock, {:laser, :r1, scan})
      lock = Lockstep.advance(lock, 0.1)
      Lockstep.latest(lock, {:drive, :r1, :_})

  A module spec is `{module, params}` or `{module, params, opts}` with
  `period: seconds` (a periodic module; without it only tuples reach the
  module), `subscribe: [template]` (as in an ADF) and `rdf:` / `wdf:`
  (this module's description files instead of the stack's: a map builder
  told nothing of a world the simulator knows, say). Every tuple
  written (`:out` actions) is kept as the latest of its `key:` (or of its
  tag and robot), delivered to the subscribers of matching templates, and
  remembered in `outs/1` until `clear_outs/1`. The `:command` of a cycle is
  handed back to the module as applied (`handle_applied/2`, `:fresh`,
  `wired: false`: there is no timing worker to own a wire, so
  `:attach_wire` actions do nothing and the module drives its device).

  Callback results are read by the same core as the runtime's
  (`ThinkingCap.Module`'s actions): a module that returns an unknown or
  malformed action raises `ThinkingCap.Module.ActionError` here as it
  would stop in the runtime. Live parameters too: `set_param/5` checks a
  change against the module's declared schema and hands it to its
  `handle_param/3`, and the accepted change is written as the runtime
  writes it (`{:param, robot, %{module:, key:, value:, by:, at:}}`).
  """

  alias ThinkingCap.Blackboard.Template
  alias ThinkingCap.Module.ActionError
  alias ThinkingCap.Module.Core.{Actions, Params}

  defstruct robot: nil,
            context: %{},
            modules: %{},
            order: [],
            subs: [],
            board: %{},
            outs: [],
            time: 0.0

  @type t :: %__MODULE__{}

  @doc "Starts the modules (their `init/2`, in order). Options: `robot`, `rdf`, `wdf`, `modules`."
  @spec new(keyword()) :: t()
  def new(opts) do
    lock = %__MODULE__{
      robot: Keyword.fetch!(opts, :robot),
      context: %{robot: opts[:robot], node: node(), rdf: opts[:rdf], wdf: opts[:wdf]}
    }

    Enum.reduce(Keyword.fetch!(opts, :modules), lock, fn {name, spec}, lock ->
      {module, params, opts} = spec(spec)
      period = opts[:period]
      activity = if period, do: :periodic, else: :event

      mparams = Params.init(module, params)

      context =
        lock.context
        |> Map.merge(%{name: name, activity: activity, handoff: nil, params: mparams.values})
        |> Map.merge(Map.new(Keyword.take(opts, [:rdf, :wdf])))

      {effects, mstate} = interpret(module.init(params, context), module, :init, activity)

      entry = %{
        module: module,
        state: mstate,
        period: period,
        next: 0.0,
        cycle: 0,
        activity: activity,
        params: mparams
      }

      lock = %{lock | modules: Map.put(lock.modules, name, entry), order: lock.order ++ [name]}
      subscribe = for t <- Keyword.get(opts, :subscribe, []), do: {:subscribe, t}
      run(lock, name, subscribe ++ effects)
    end)
  end

  defp spec({module, params}), do: {module, params, []}
  defp spec({module, params, opts}), do: {module, params, opts}

  @doc "Writes a tuple, as a sensor or another node would; its subscribers run at once."
  @spec deliver(t(), tuple()) :: t()
  def deliver(lock, tuple), do: lock |> store(tuple, []) |> deliver_to_subscribers(tuple)

  @doc "Advances the clock to `time`, releasing every periodic module due (in ADF order)."
  @spec advance(t(), float()) :: t()
  def advance(lock, time) do
    due =
      for name <- lock.order,
          %{period: p, next: next} = lock.modules[name],
          p != nil and next <= time + 1.0e-9,
          do: name

    lock = Enum.reduce(due, %{lock | time: time}, &release(&2, &1, time))
    if due == [], do: lock, else: advance(lock, time)
  end

  defp release(lock, name, time) do
    %{module: m, state: s, cycle: n, period: p, next: next} = lock.modules[name]

    release = %{
      id: 0,
      cycle: n,
      scheduled_ns: round(next * 1.0e9),
      released_ns: round(time * 1.0e9),
      timer_late_ns: 0
    }

    {[{:cycle_result, command, _wire} | effects], s} =
      interpret(m.handle_cycle(release, s), m, :handle_cycle, :periodic)

    lock =
      lock
      |> put_state(name, s)
      |> update_in([Access.key(:modules), name], &%{&1 | cycle: n + 1, next: next + p})
      |> run(name, effects)

    case command do
      nil ->
        lock

      command ->
        %{module: m, state: s} = lock.modules[name]

        applied = %{
          cycle: n,
          kind: :fresh,
          command: command,
          wired: false,
          response_us: 0.0,
          applied_ns: release.released_ns
        }

        {effects, s} = interpret(m.handle_applied(applied, s), m, :handle_applied, :periodic)
        lock |> put_state(name, s) |> run(name, effects)
    end
  end

  @doc "The latest tuple matching `template` on the private blackboard, or nil."
  @spec latest(t(), tuple()) :: tuple() | nil
  def latest(lock, template) do
    compiled = Template.compile(template)

    Enum.find_value(lock.board, fn {_key, tuple} ->
      Template.matches?(compiled, tuple) && tuple
    end)
  end

  @doc "Every tuple written since the start (or `clear_outs/1`), oldest first."
  @spec outs(t()) :: [tuple()]
  def outs(lock), do: Enum.reverse(lock.outs)

  @doc "Forgets the tuples `outs/1` would return."
  @spec clear_outs(t()) :: t()
  def clear_outs(lock), do: %{lock | outs: []}

  @doc "A module's state (to look inside in tests)."
  @spec state(t(), atom()) :: term()
  def state(lock, name), do: lock.modules[name].state

  @doc "A module's params as they stand (its declared fields with their defaults)."
  @spec params(t(), atom()) :: map()
  def params(lock, name), do: lock.modules[name].params.values

  @doc """
  Sets module `name`'s param `key` to `value` while it runs, as
  `ThinkingCap.Runtime.set_param/4` does: checked against the module's
  schema, handed to its `handle_param/3`, recorded as a `{:param, ...}`
  tuple. Options: `by:` who asks (default `:test`).
  """
  @spec set_param(t(), atom(), atom(), term(), keyword()) :: {:ok, t()} | {:error, String.t()}
  def set_param(lock, name, key, value, opts \\ []) do
    case set(lock, name, key, value, Keyword.get(opts, :by, :test), false) do
      {:ok, lock} -> {:ok, lock}
      # a refusal changes nothing
      {:error, message, _lock} -> {:error, message}
    end
  end

  defp set(lock, name, key, value, by, own) do
    %{module: m, state: s, activity: activity, params: params} = lock.modules[name]

    case Params.set(params, m, s, key, value, activity, own) do
      {:ok, value, effects, s, params} ->
        {tuple, opts} = Params.record(lock.robot, name, key, value, by)

        lock =
          lock
          |> put_state(name, s)
          |> then(&put_in(&1.modules[name].params, params))
          |> publish(tuple, opts)
          |> run(name, effects)

        {:ok, lock}

      {:error, message, s} ->
        {:error, message, put_state(lock, name, s)}

      {:crash, error} ->
        raise error
    end
  end

  defp run(lock, _name, []), do: lock

  defp run(lock, name, [effect | rest]) do
    lock =
      case effect do
        {:out, tuple, opts} ->
          publish(lock, tuple, opts)

        {:subscribe, template} ->
          %{lock | subs: lock.subs ++ [{name, Template.compile(template)}]}

        # no timing worker here: a wire is not attached, its bytes go nowhere
        {:attach_wire, _device, _fallback} ->
          lock

        :detach_wire ->
          lock

        {:set_param, key, value} ->
          case set(lock, name, key, value, {:module, name}, true) do
            {:ok, lock} -> lock
            {:error, _message, lock} -> lock
          end

        {:warning, _message} ->
          lock
      end

    run(lock, name, rest)
  end

  defp publish(lock, tuple, opts) do
    lock = %{store(lock, tuple, opts) | outs: [tuple | lock.outs]}
    deliver_to_subscribers(lock, tuple)
  end

  defp deliver_to_subscribers(lock, tuple) do
    Enum.reduce(lock.subs, lock, fn {name, template}, lock ->
      if Template.matches?(template, tuple) do
        %{module: m, state: s, activity: activity} = lock.modules[name]
        {effects, s} = interpret(m.handle_tuple(tuple, s), m, :handle_tuple, activity)
        lock |> put_state(name, s) |> run(name, effects)
      else
        lock
      end
    end)
  end

  defp store(lock, tuple, opts) do
    key = Keyword.get_lazy(opts, :key, fn -> default_key(tuple) end)
    %{lock | board: Map.put(lock.board, key, tuple)}
  end

  defp default_key(tuple) when tuple_size(tuple) >= 2, do: {elem(tuple, 0), elem(tuple, 1)}
  defp default_key(tuple), do: tuple

  defp put_state(lock, name, s), do: put_in(lock.modules[name].state, s)

  # the one reading of a callback's result, the runtime's (Core.Actions)
  defp interpret(result, module, callback, activity) do
    case Actions.interpret(result, module, callback, activity) do
      {:ok, effects, state} -> {effects, state}
      {:error, %ActionError{} = error} -> raise error
    end
  end
end
