defmodule ThinkingCap.Runtime.Host do
  @moduledoc false
  # The process that hosts one module: runs its callbacks, executes their
  # actions, owns its subscriptions and its periodic activity in the cycle.
  # Process priority follows the activity: periodic high, event normal,
  # background low (it runs when nothing else does).
  # transient: a crash is restarted by its layer (and counts against the
  # layer's intensity); an exit with :shutdown or {:shutdown, _} is not:
  # an operator's restart (Supervision.restart_host/1) starts it again
  # itself, uncounted
  use GenServer, restart: :transient
  require Logger

  alias ThinkingCap.{Blackboard, Cycle}
  alias ThinkingCap.Module.Core.{Actions, Params}
  alias ThinkingCap.Runtime.Trace

  # the count of the module's callbacks since its init, for its trace
  @trace_n :"$tc_trace_n"
  # its traced callbacks held for the batched sinks: {count, newest first}
  @trace_held :"$tc_trace_held"

  def start_link(spec), do: GenServer.start_link(__MODULE__, spec)

  def child_spec(spec),
    do: %{
      id: {__MODULE__, spec.name},
      start: {__MODULE__, :start_link, [spec]},
      restart: :transient
    }

  @impl true
  def init(spec) do
    Process.flag(:trap_exit, true)
    # what it was started with: read by an operator's restart even when
    # the module is stuck in a callback
    Process.put(:"$tc_spec", spec)
    spec = Map.put(spec, :layer, ThinkingCap.Runtime.Supervision.layer_of(spec))
    # its robot's warden watches it before its module's init/2 runs
    ThinkingCap.Runtime.Supervision.Warden.hosting(spec.robot, spec.layer, spec.name)
    Process.flag(:priority, priority(spec.activity))
    Enum.each(groups(spec), &(:ok = :pg.join(ThinkingCap.Runtime.scope(), &1, self())))

    params = Params.init(spec.module, spec.params)

    context = %{
      name: spec.name,
      robot: spec.robot,
      node: node(),
      activity: spec.activity,
      rdf: Map.get(spec, :rdf),
      wdf: Map.get(spec, :wdf),
      handoff: Map.get(spec, :handoff),
      params: params.values
    }

    traced = Trace.traced?(spec.module)
    Process.put(@trace_n, 0)

    init = fn ->
      {:init,
       %{
         module: spec.module,
         params: spec.params,
         context: context,
         activity: spec.activity,
         period: Map.get(spec, :period),
         node: node()
       }}
    end

    {effects, module_state} =
      trace(spec, traced, init, fn ->
        interpret(spec.module.init(spec.params, context), spec.module, :init, spec.activity)
      end)

    state = %{
      spec: spec,
      module: spec.module,
      mstate: module_state,
      context: context,
      params: params,
      traced: traced,
      started: System.system_time(:millisecond)
    }

    case activate(spec) do
      :ok ->
        for template <- spec.subscribe,
            do: {:ok, _} = Blackboard.subscribe(template, max_queue: 10_000)

        if handing_off?(spec), do: send(self(), :tc_handoff)
        {:ok, run(effects, state)}

      {:error, reason} ->
        # the module's init may have opened what its terminate closes; and
        # once start returns, no lookup finds this process
        spec.module.terminate(reason, module_state)
        Enum.each(groups(spec), &:pg.leave(ThinkingCap.Runtime.scope(), &1, self()))
        {:stop, reason}
    end
  end

  defp activate(%{activity: :periodic} = spec) do
    opts = [
      period: spec.period,
      deadline: spec.deadline,
      lead: spec.lead,
      priority: spec.priority,
      fallback: spec.fallback
    ]

    case Cycle.add(spec.name, opts) do
      :ok -> :ok
      # a periodic activity is known to this node's timing worker by name
      {:error, {:name_taken, pid}} -> {:error, {:periodic_name_taken_on_node, spec.name, pid}}
    end
  end

  defp activate(%{activity: :background}) do
    send(self(), :tc_background)
    :ok
  end

  defp activate(%{activity: :event}), do: :ok

  # Deployment gives `handoff_to`: the other nodes of [node | standby]
  defp handing_off?(spec),
    do: Map.get(spec, :handoff_to, []) != [] and function_exported?(spec.module, :handoff, 1)

  @impl true
  def handle_info({:tc_cycle, :release, name, release}, %{spec: %{name: name}} = state) do
    # a release that queued up behind a slow cycle is stale: keep the newest
    release = newest_release(name, release)
    :ok = Cycle.await_release(release)
    started = System.monotonic_time()

    {[{:cycle_result, command, wire} | effects], mstate} =
      callback(state, :handle_cycle, [release, state.mstate])

    if wire, do: Cycle.result(release, command, wire), else: Cycle.result(release, command)

    Cycle.record_cpu(
      release,
      System.convert_time_unit(System.monotonic_time() - started, :native, :nanosecond)
    )

    {:noreply, run(effects, %{state | mstate: mstate})}
  end

  def handle_info({:tc_cycle, :applied, name, event}, %{spec: %{name: name}} = state) do
    {effects, mstate} = callback(state, :handle_applied, [event, state.mstate])
    {:noreply, run(effects, %{state | mstate: mstate})}
  end

  def handle_info({:blackboard, _ref, tuple}, state) do
    {effects, mstate} = callback(state, :handle_tuple, [tuple, state.mstate])
    {:noreply, run(effects, %{state | mstate: mstate})}
  end

  def handle_info(:tc_background, state) do
    {effects, mstate} = callback(state, :handle_background, [state.mstate])
    send(self(), :tc_background)
    {:noreply, run(effects, %{state | mstate: mstate})}
  end

  def handle_info({:tc_run_effects, effects}, state), do: {:noreply, run(effects, state)}

  def handle_info(:tc_trace_flush, state) do
    flush_trace(state.spec)
    {:noreply, state}
  end

  # never blocking on a busy or dead link (:noconnect): a handoff lost is
  # replaced by the next one
  def handle_info(:tc_handoff, %{spec: spec} = state) do
    Process.send_after(self(), :tc_handoff, round(Map.get(spec, :handoff_every, 1.0) * 1000))

    try do
      handoff = {:tc_handoff, spec.robot, spec.name, state.module.handoff(state.mstate)}

      for node <- spec.handoff_to,
          do: Process.send({ThinkingCap.Runtime.Deployment, node}, handoff, [:noconnect])
    rescue
      e -> Logger.error("#{inspect(spec.name)}: handoff/1 failed: #{Exception.message(e)}")
    end

    {:noreply, state}
  end

  def handle_info({:EXIT, _pid, reason}, state) when reason in [:normal, :shutdown],
    do: {:noreply, state}

  def handle_info(message, state) do
    {effects, mstate} = callback(state, :handle_info, [message, state.mstate])
    {:noreply, run(effects, %{state | mstate: mstate})}
  end

  @impl true
  def handle_call(:info, _from, state) do
    info = %{
      name: state.spec.name,
      robot: state.spec.robot,
      module: state.module,
      node: node(),
      pid: self(),
      activity: state.spec.activity,
      layer: state.spec.layer,
      started_at: state.started
    }

    {:reply, info, state}
  end

  def handle_call(:params, _from, state) do
    params = %{
      name: state.spec.name,
      robot: state.spec.robot,
      module: state.module,
      live: state.params.live,
      values: state.params.values,
      fields: Params.describe(state.params)
    }

    {:reply, params, state}
  end

  # a live change of a param (ThinkingCap.Runtime.set_param/4): checked,
  # seen by the module's handle_param/3, recorded on the blackboard; a
  # release queued meanwhile sees the new value
  def handle_call({:set_param, key, value, by}, _from, state) do
    case set_param(state, key, value, by, false) do
      {:ok, state} -> {:reply, :ok, state}
      {:error, message, state} -> {:reply, {:error, message}, state}
    end
  end

  # Replaced in place, between two messages: the activity, its cycle slot
  # and its subscriptions stay, so no release is missed.
  def handle_call({:swap, new_module}, _from, state) do
    traced = Trace.traced?(new_module)

    {effects, mstate} =
      trace(state.spec, traced, fn -> {:swap, new_module} end, fn ->
        if Code.ensure_loaded?(new_module) and function_exported?(new_module, :handle_swap, 3) do
          {[], _mstate} =
            new_module.handle_swap(state.module, state.mstate, state.context)
            |> interpret(new_module, :handle_swap, state.spec.activity)
        else
          new_module.init(state.spec.params, state.context)
          |> interpret(new_module, :init, state.spec.activity)
        end
      end)

    # init's actions run below, with the new module in place
    if effects != [], do: send(self(), {:tc_run_effects, effects})

    state.module.terminate(:swapped, state.mstate)
    # the new module's schema, the values set so far kept where it declares them
    params = Params.init(new_module, state.spec.params)

    params = %{
      params
      | values: Map.merge(params.values, Map.take(state.params.values, Map.keys(params.values)))
    }

    {:reply, :ok,
     %{
       state
       | module: new_module,
         mstate: mstate,
         params: params,
         traced: traced,
         context: %{state.context | params: params.values},
         spec: %{state.spec | module: new_module}
     }}
  end

  @impl true
  def terminate(reason, state) do
    flush_trace(state.spec)
    # leave at once: when stop/1 returns the module is gone from whereis/1
    # on this node (pg would otherwise drop it when it sees the exit)
    Enum.each(groups(state.spec), &:pg.leave(ThinkingCap.Runtime.scope(), &1, self()))
    state.module.terminate(reason, state.mstate)
  end

  ## Helpers

  # found by name, and by robot and name (two robots of one cluster may
  # both run a module of the same name)
  defp groups(spec), do: [{:module, spec.name}, {:module, spec.robot, spec.name}]

  defp priority(:periodic), do: :high
  defp priority(:event), do: :normal
  defp priority(:background), do: :low

  defp newest_release(name, release) do
    receive do
      {:tc_cycle, :release, ^name, newer} -> newest_release(name, newer)
    after
      0 -> release
    end
  end

  # a callback's result read by the one core both Host and Lockstep use
  # (ThinkingCap.Module.Core.Actions); what it cannot read stops the module
  # with an error naming the module and the callback
  defp callback(state, name, args) do
    trace(state.spec, state.traced, fn -> Trace.input(name, args, state.spec.robot) end, fn ->
      interpret(apply(state.module, name, args), state.module, name, state.spec.activity)
    end)
  end

  # Runs a callback (`run` gives {effects, mstate}) and, while the robot's
  # trace has sinks (it is being recorded), sends them its input and its
  # outputs, or what it raised (ThinkingCap.Runtime.Trace): at once to
  # the plain sinks, in lists to the batched ones.
  defp trace(spec, traced, input, run) do
    n = Process.get(@trace_n, 0)
    Process.put(@trace_n, n + 1)

    case if(traced, do: trace_sinks(spec.robot), else: :none) do
      :none ->
        run.()

      sinks ->
        try do
          {effects, mstate} = run.()
          outputs = if is_list(effects), do: Trace.outputs(effects, spec.robot), else: effects
          emit(spec, sinks, n, {input.(), outputs})
          {effects, mstate}
        catch
          kind, reason ->
            emit(spec, sinks, n, {input.(), raised(kind, reason)})
            flush_trace(spec)
            :erlang.raise(kind, reason, __STACKTRACE__)
        end
    end
  end

  defp trace_sinks(robot) do
    case {Trace.plain_sinks(robot), Trace.batch_sinks(robot)} do
      {[], []} -> :none
      sinks -> sinks
    end
  end

  defp emit(spec, {plain, batched}, n, event) do
    if plain != [], do: Trace.send(plain, spec.robot, spec.name, n, event)
    if batched != [], do: hold_trace(spec, {n, :erlang.monotonic_time(), event})
  end

  # held until Trace.batching/1's count, or its delay after the first
  defp hold_trace(spec, item) do
    {max_batch, delay} = Trace.batching(spec.robot)

    case Process.get(@trace_held, {0, []}) do
      {0, _} ->
        Process.send_after(self(), :tc_trace_flush, delay)
        Process.put(@trace_held, {1, [item]})

      {count, items} when count + 1 >= max_batch ->
        Process.put(@trace_held, {0, []})
        send_trace(spec, [item | items])

      {count, items} ->
        Process.put(@trace_held, {count + 1, [item | items]})
    end
  end

  defp flush_trace(spec) do
    case Process.put(@trace_held, {0, []}) do
      {_, [_ | _] = items} -> send_trace(spec, items)
      _nothing -> :ok
    end
  end

  defp send_trace(spec, newest_first),
    do:
      Trace.send_batch(
        Trace.batch_sinks(spec.robot),
        spec.robot,
        spec.name,
        Enum.reverse(newest_first)
      )

  defp raised(kind, reason),
    do: {:raised, kind, kind |> Exception.format_banner(reason) |> String.slice(0, 500)}

  defp interpret(result, module, callback, activity) do
    case Actions.interpret(result, module, callback, activity) do
      {:ok, effects, mstate} -> {effects, mstate}
      {:error, error} -> raise error
    end
  end

  defp set_param(state, key, value, by, own) do
    set = fn ->
      Params.set(state.params, state.module, state.mstate, key, value, state.spec.activity, own)
    end

    # a change asked from outside is an input of the module: traced (its
    # own changes are its outputs, traced with the callback that asked)
    result = if own, do: set.(), else: trace_param(state, key, value, set)

    case result do
      {:ok, value, effects, mstate, params} ->
        {tuple, opts} = Params.record(state.spec.robot, state.spec.name, key, value, by)
        Blackboard.out(tuple, opts)

        state = %{
          state
          | mstate: mstate,
            params: params,
            context: %{state.context | params: params.values}
        }

        {:ok, run(effects, state)}

      {:error, message, mstate} ->
        {:error, message, %{state | mstate: mstate}}

      {:crash, error} ->
        raise error
    end
  end

  defp trace_param(state, key, value, set) do
    {_, result} =
      trace(state.spec, state.traced, fn -> {:param, key, value} end, fn ->
        case set.() do
          {:ok, _value, effects, _mstate, _params} = ok -> {effects, ok}
          {:error, message, _mstate} = error -> {{:refused, message}, error}
          {:crash, error} -> raise error
        end
      end)

    result
  end

  # the module keeps running without a wire when its device cannot be opened
  # (Core.Actions lets :attach_wire through for periodic modules only)
  defp attach_wire(%{spec: %{name: name}}, device, fallback) do
    case Cycle.attach_wire(name, device, fallback) do
      :ok ->
        :ok

      {:error, message} ->
        Logger.error(
          "#{inspect(name)}: the timing worker cannot own the command path of " <>
            "#{inspect(device)}: #{message}; the module's commands are not on that line"
        )
    end
  end

  defp run([], state), do: state

  defp run([effect | rest], state) do
    state =
      case effect do
        {:out, tuple, opts} ->
          Blackboard.out(tuple, opts)
          state

        {:subscribe, template} ->
          {:ok, _} = Blackboard.subscribe(template, max_queue: 10_000)
          state

        {:attach_wire, device, fallback} ->
          attach_wire(state, device, fallback)
          state

        :detach_wire ->
          :ok = Cycle.detach_wire(state.spec.name)
          state

        {:set_param, key, value} ->
          case set_param(state, key, value, {:module, state.spec.name}, true) do
            {:ok, state} ->
              state

            {:error, message, state} ->
              Logger.warning("#{inspect(state.spec.name)}: a :set_param action: #{message}")
              state
          end

        {:warning, message} ->
          Logger.warning("#{inspect(state.spec.name)}: #{message}")
          state
      end

    run(rest, state)
  end
end
