defmodule ThinkingCap.Runtime.Host do
  @moduledoc false
  # The process that hosts one module: runs its callbacks, executes their
  # actions, owns its subscriptions and its periodic activity in the cycle.
  # Process priority follows the activity: periodic high, event normal,
  # background low (it runs when nothing else does).
  use GenServer, restart: :permanent
  require Logger

  alias ThinkingCap.{Blackboard, Cycle}

  def start_link(spec), do: GenServer.start_link(__MODULE__, spec)

  def child_spec(spec),
    do: %{
      id: {__MODULE__, spec.name},
      start: {__MODULE__, :start_link, [spec]},
      restart: :permanent
    }

  @impl true
  def init(spec) do
    Process.flag(:trap_exit, true)
    Process.flag(:priority, priority(spec.activity))
    Enum.each(groups(spec), &(:ok = :pg.join(ThinkingCap.Runtime.scope(), &1, self())))

    context = %{
      name: spec.name,
      robot: spec.robot,
      node: node(),
      activity: spec.activity,
      rdf: Map.get(spec, :rdf),
      wdf: Map.get(spec, :wdf),
      handoff: Map.get(spec, :handoff)
    }

    {actions, module_state} =
      normalize(spec.module.init(spec.params, context), spec.module, :init)

    state = %{
      spec: spec,
      module: spec.module,
      mstate: module_state,
      context: context,
      started: System.system_time(:millisecond)
    }

    case activate(spec) do
      :ok ->
        for template <- spec.subscribe,
            do: {:ok, _} = Blackboard.subscribe(template, max_queue: 10_000)

        if handing_off?(spec), do: send(self(), :tc_handoff)
        {:ok, run(actions, state)}

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
    started = System.monotonic_time()

    {actions, mstate} =
      normalize(state.module.handle_cycle(release, state.mstate), state.module, :handle_cycle)

    {command, actions} = take_last(actions, :command)
    {wire, actions} = take_last(actions, :wire)
    if wire, do: Cycle.result(release, command, wire), else: Cycle.result(release, command)

    Cycle.record_cpu(
      release,
      System.convert_time_unit(System.monotonic_time() - started, :native, :nanosecond)
    )

    {:noreply, run(actions, %{state | mstate: mstate})}
  end

  def handle_info({:tc_cycle, :applied, name, event}, %{spec: %{name: name}} = state) do
    {actions, mstate} =
      normalize(state.module.handle_applied(event, state.mstate), state.module, :handle_applied)

    {:noreply, run(actions, %{state | mstate: mstate})}
  end

  def handle_info({:blackboard, _ref, tuple}, state) do
    {actions, mstate} =
      normalize(state.module.handle_tuple(tuple, state.mstate), state.module, :handle_tuple)

    {:noreply, run(actions, %{state | mstate: mstate})}
  end

  def handle_info(:tc_background, state) do
    {actions, mstate} =
      normalize(state.module.handle_background(state.mstate), state.module, :handle_background)

    send(self(), :tc_background)
    {:noreply, run(actions, %{state | mstate: mstate})}
  end

  def handle_info({:tc_run_actions, actions}, state), do: {:noreply, run(actions, state)}

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
    {actions, mstate} =
      normalize(state.module.handle_info(message, state.mstate), state.module, :handle_info)

    {:noreply, run(actions, %{state | mstate: mstate})}
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
      started_at: state.started
    }

    {:reply, info, state}
  end

  # Replaced in place, between two messages: the activity, its cycle slot
  # and its subscriptions stay, so no release is missed.
  def handle_call({:swap, new_module}, _from, state) do
    mstate =
      if Code.ensure_loaded?(new_module) and function_exported?(new_module, :handle_swap, 3) do
        {:ok, mstate} = new_module.handle_swap(state.module, state.mstate, state.context)
        mstate
      else
        {actions, mstate} =
          normalize(new_module.init(state.spec.params, state.context), new_module, :init)

        # init's actions run below, with the new module in place
        send(self(), {:tc_run_actions, actions})
        mstate
      end

    state.module.terminate(:swapped, state.mstate)

    {:reply, :ok,
     %{state | module: new_module, mstate: mstate, spec: %{state.spec | module: new_module}}}
  end

  @impl true
  def terminate(reason, state) do
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

  defp normalize({:ok, state}, _module, _callback), do: {[], state}
  defp normalize({actions, state}, _module, _callback) when is_list(actions), do: {actions, state}

  defp normalize(other, module, callback) do
    raise ArgumentError,
          "#{inspect(module)}.#{callback} must return {actions, state} (or {:ok, state} from init), got: #{inspect(other, limit: 10)}"
  end

  # the last {key, value} action of handle_cycle (nil without one), and the others
  defp take_last(actions, key) do
    case Enum.split_with(actions, &match?({^key, _}, &1)) do
      {[], rest} -> {nil, rest}
      {taken, rest} -> {taken |> List.last() |> elem(1), rest}
    end
  end

  # the module keeps running without a wire when its device cannot be opened
  defp attach_wire(%{spec: %{activity: :periodic, name: name}}, device, fallback) do
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

  defp attach_wire(state, device, _fallback) do
    Logger.error(
      "#{inspect(state.spec.name)}: an :attach_wire action (#{inspect(device)}) needs a periodic activity"
    )
  end

  defp run([], state), do: state

  defp run([action | rest], state) do
    case action do
      {:out, {tuple, opts}} when is_tuple(tuple) and is_list(opts) ->
        Blackboard.out(tuple, opts)

      {:out, tuple} when is_tuple(tuple) ->
        Blackboard.out(tuple)

      {:subscribe, template} ->
        {:ok, _} = Blackboard.subscribe(template, max_queue: 10_000)

      {kind, _} when kind in [:command, :wire] ->
        Logger.warning(
          "#{inspect(state.spec.name)}: a #{inspect(kind)} action only counts in handle_cycle/2"
        )

      {:attach_wire, device, fallback} ->
        attach_wire(state, device, fallback)

      {:detach_wire} ->
        if state.spec.activity == :periodic, do: :ok = Cycle.detach_wire(state.spec.name)

      other ->
        raise ArgumentError,
              "#{inspect(state.module)}: unknown action #{inspect(other, limit: 10)}"
    end

    run(rest, state)
  end
end
