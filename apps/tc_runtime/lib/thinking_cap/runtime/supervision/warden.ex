defmodule ThinkingCap.Runtime.Supervision.Warden do
  @moduledoc false
  # Watches one robot's layers on this node (ThinkingCap.Runtime.Supervision).
  # Every module host tells it when it starts (a call: the host is watched
  # before its module's init/2 runs, so a crash in init is seen with its
  # reason). It remembers, per layer, the modules it hosts and the last
  # crash; when a layer's supervisor exits (it exceeded its restart
  # intensity: nothing else stops a layer while the warden runs), it
  # latches the robot's E-stop and writes `{:module_gave_up, robot, ...}`.
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Runtime.Supervision
  alias ThinkingCap.Tuples
  require Tuples

  def start_link(robot),
    do: GenServer.start_link(__MODULE__, robot, name: Supervision.via({:warden, robot}))

  def child_spec(robot),
    do: %{id: __MODULE__, start: {__MODULE__, :start_link, [robot]}, restart: :permanent}

  @doc false
  # From a host's init: watch it. Never fails the host.
  def hosting(robot, layer, name) do
    case Supervision.lookup({:warden, robot}) do
      nil -> :ok
      warden -> GenServer.call(warden, {:hosting, layer, name, self()}, 5_000)
    end
  catch
    :exit, _ -> :ok
  end

  @doc false
  # Before a host is stopped on purpose (Runtime.stop/1): it no longer
  # counts among its layer's modules.
  def stopping(pid) do
    with {:parent, sup} when is_pid(sup) <- Process.info(pid, :parent),
         [{:layer, robot, _layer}] <- Registry.keys(Supervision.registry(), sup),
         warden when is_pid(warden) <- Supervision.lookup({:warden, robot}) do
      GenServer.call(warden, {:stopping, pid}, 5_000)
    else
      _ -> :ok
    end
  catch
    :exit, _ -> :ok
  end

  @doc false
  # After layers were started again (Supervision.resume_here/1).
  def resumed(robot) do
    case Supervision.lookup({:warden, robot}) do
      nil -> :ok
      warden -> GenServer.call(warden, :watch_layers, 5_000)
    end
  end

  @impl true
  def init(robot) do
    state = %{robot: robot, layers: %{}, hosts: %{}, members: %{}, crashes: %{}}
    {:ok, watch_layers(state)}
  end

  @impl true
  def handle_call({:hosting, layer, name, pid}, _from, state) do
    ref = Process.monitor(pid)
    members = Map.update(state.members, layer, MapSet.new([name]), &MapSet.put(&1, name))

    {:reply, :ok,
     %{state | hosts: Map.put(state.hosts, ref, {layer, name, pid}), members: members}}
  end

  def handle_call({:stopping, pid}, _from, state) do
    members =
      Enum.reduce(state.hosts, state.members, fn
        {_ref, {layer, name, ^pid}}, members ->
          Map.update!(members, layer, &MapSet.delete(&1, name))

        _other, members ->
          members
      end)

    {:reply, :ok, %{state | members: members}}
  end

  def handle_call(:watch_layers, _from, state), do: {:reply, :ok, watch_layers(state)}

  @impl true
  def handle_info({:DOWN, ref, :process, _pid, reason}, state) do
    cond do
      Map.has_key?(state.hosts, ref) ->
        {{layer, name, _pid}, hosts} = Map.pop(state.hosts, ref)
        state = %{state | hosts: hosts}

        if crash?(reason),
          do: {:noreply, put_in(state.crashes[layer], {name, reason})},
          else: {:noreply, state}

      Map.has_key?(state.layers, ref) ->
        {layer, layers} = Map.pop(state.layers, ref)
        {:noreply, gave_up(%{state | layers: layers}, layer)}

      true ->
        {:noreply, state}
    end
  end

  def handle_info(_other, state), do: {:noreply, state}

  defp watch_layers(state) do
    watched = Map.values(state.layers)

    layers =
      for layer <- Supervision.layer_names(),
          layer not in watched,
          pid = Supervision.lookup({:layer, state.robot, layer}),
          into: state.layers,
          do: {Process.monitor(pid), layer}

    %{state | layers: layers}
  end

  defp crash?(:normal), do: false
  defp crash?(:shutdown), do: false
  defp crash?({:shutdown, _}), do: false
  defp crash?(_reason), do: true

  # The layer exceeded its restart intensity: its modules are stopped
  # already (their activities' fallbacks applied). Latch the robot's stop
  # and say which module gave up.
  defp gave_up(state, layer) do
    robot = state.robot
    {name, reason} = Map.get(state.crashes, layer, {nil, :unknown})
    stopped = state.members |> Map.get(layer, MapSet.new()) |> Enum.sort()
    {restarts, seconds} = Keyword.fetch!(Supervision.layers(), layer)
    at = System.os_time(:millisecond)
    who = if name, do: "module #{name}", else: "a module"

    Logger.error(
      "robot #{inspect(robot)}: #{who} of layer #{inspect(layer)} gave up " <>
        "(more than #{restarts} restarts in #{seconds} s; last: #{describe(reason)}); " <>
        "stopped with it: #{inspect(stopped)}; E-stop latched"
    )

    {estop, opts} = Tuples.keyed(Tuples.estop_engaged(robot, "runtime: #{who} gave up", at))
    Blackboard.out(estop, opts)

    gave_up =
      Tuples.module_gave_up(
        robot,
        %{
          module: name,
          layer: layer,
          node: node(),
          reason: describe(reason),
          restarts: restarts,
          seconds: seconds,
          stopped: stopped,
          at: at
        }
      )

    {gave_up, opts} = Tuples.keyed(gave_up)
    Blackboard.out(gave_up, opts)

    %{
      state
      | members: Map.delete(state.members, layer),
        crashes: Map.delete(state.crashes, layer)
    }
  end

  # a crash's reason in a line: the exception's message, or the exit term
  defp describe({exception, stack}) when is_exception(exception) and is_list(stack),
    do: describe(exception)

  defp describe(exception) when is_exception(exception),
    do: truncate("#{inspect(exception.__struct__)}: #{Exception.message(exception)}")

  defp describe(reason), do: truncate(inspect(reason, limit: 8, printable_limit: 200))

  defp truncate(text) when byte_size(text) > 300, do: String.slice(text, 0, 297) <> "..."
  defp truncate(text), do: text
end
