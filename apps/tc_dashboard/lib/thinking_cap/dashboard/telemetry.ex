defmodule ThinkingCap.Dashboard.Telemetry do
  @moduledoc """
  Collects what the dashboard shows, once per node however many browsers
  watch: it subscribes to the blackboard's latest-value streams, encodes
  each changed stream to JSON at most `telemetry_hz` times a second, and
  keeps the result in an ETS table with a version number. Every browser's
  session then takes, at its own pace, what changed since the version it
  last saw (`changes_since/1`), so a slow browser gets fewer, fresher frames
  and never a queue, and the blackboard's writers never wait for a browser.

  Streams: `#{inspect(~w(sim_pose sim_walkers pose odom laser sonar lps plan activation control robot bumper beacons estop timing door map particles topology black_box_dump)a)}`
  (`{tag, id, payload}` tuples, keyed `"tag/id"`), plus `modules/all`, the
  modules running in the cluster, once a second, with those whose layer
  gave up (`{:module_gave_up, robot, _}`, `ThinkingCap.Runtime.Supervision`)
  and are not running again: `status: "gave_up"`, the `reason` and the
  modules stopped with them (`status: "stopped"`). A learned map (`map`)
  of more than #{ThinkingCap.Dashboard.Core.Payload.map_cells()} cells is shrunk for display
  (`ThinkingCap.Navigation.OccupancyGrid.shrink/2`), its cells sent as
  base64.
  """
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Core.{JSON, Payload}
  alias ThinkingCap.Tuples
  require Tuples

  @table __MODULE__
  # the vocabulary's streams, and the sensors' conventional names
  @streams [
    Tuples.tag(:sim_pose),
    Tuples.tag(:sim_walkers),
    Tuples.tag(:pose),
    :odom,
    :laser,
    :sonar,
    Tuples.tag(:lps),
    Tuples.tag(:plan),
    Tuples.tag(:activation),
    Tuples.tag(:control),
    Tuples.tag(:robot),
    :bumper,
    :beacons,
    Tuples.tag(:estop),
    Tuples.tag(:timing),
    Tuples.tag(:door),
    Tuples.tag(:map),
    Tuples.tag(:particles),
    Tuples.tag(:topology),
    Tuples.tag(:black_box_dump)
  ]
  @modules_every 1_000

  @doc false
  def start_link(config), do: GenServer.start_link(__MODULE__, config, name: __MODULE__)

  @doc false
  def child_spec(config),
    do: %{id: __MODULE__, start: {__MODULE__, :start_link, [config]}, restart: :permanent}

  @doc """
  The streams changed since `version`: `{latest_version, [{key, json}]}`
  (json is the encoded payload, `"null"` for a stream that went away).
  """
  @spec changes_since(non_neg_integer()) :: {non_neg_integer(), [{String.t(), binary()}]}
  def changes_since(version) do
    latest =
      case :ets.lookup(@table, :version) do
        [{:version, v}] -> v
        [] -> 0
      end

    if latest == version do
      {latest, []}
    else
      items =
        :ets.select(@table, [
          {{{:item, :"$1"}, :"$2", :"$3"}, [{:>, :"$2", version}], [{{:"$1", :"$3"}}]}
        ])

      {latest, items}
    end
  catch
    :error, :badarg -> {version, []}
  end

  @doc "The world (the WDF shown on the map) as JSON, or `\"null\"`."
  @spec world_json() :: binary()
  def world_json do
    case :ets.lookup(@table, :world) do
      [{:world, json}] -> json
      [] -> "null"
    end
  catch
    :error, :badarg -> "null"
  end

  @doc "The names of the world's waypoints, rooms and corridors (strings)."
  @spec world_places() :: [String.t()]
  def world_places do
    case :ets.lookup(@table, :places) do
      [{:places, names}] -> names
      [] -> []
    end
  catch
    :error, :badarg -> []
  end

  @impl true
  def init(config) do
    table = :ets.new(@table, [:named_table, :protected, :set, read_concurrency: true])
    wdf = read_world(config.world)
    :ets.insert(table, [{:version, 0}, {:world, world(wdf)}, {:places, places(wdf)}])

    for tag <- @streams, do: {:ok, _} = Blackboard.subscribe({tag, :_, :_})

    dirty =
      for tag <- @streams, {^tag, id, payload} <- Blackboard.rd_all({tag, :_, :_}), into: %{} do
        {key(tag, id), payload}
      end

    interval = max(div(1000, config.telemetry_hz), 1)
    :timer.send_interval(interval, :flush)
    send(self(), :modules)

    {:ok,
     %{table: table, version: 0, dirty: dirty, modules: nil, pids: %{}, restarts: %{}, task: nil}}
  end

  @impl true
  def handle_info({:blackboard, _ref, {tag, id, payload}}, state),
    do: {:noreply, %{state | dirty: Map.put(state.dirty, key(tag, id), payload)}}

  def handle_info(:flush, %{dirty: dirty} = state) when map_size(dirty) == 0,
    do: {:noreply, state}

  def handle_info(:flush, state) do
    version = state.version + 1

    rows =
      for {key, payload} <- state.dirty do
        {{:item, key}, version, Payload.encode(key, payload)}
      end

    :ets.insert(state.table, rows)
    :ets.insert(state.table, {:version, version})
    {:noreply, %{state | version: version, dirty: %{}}}
  end

  # which_modules asks every module: done in a task, never blocking the
  # collection of streams
  def handle_info(:modules, %{task: nil} = state) do
    task =
      Task.async(fn ->
        {ThinkingCap.Runtime.which_modules(), Blackboard.rd_all(Tuples.module_gave_up())}
      end)

    {:noreply, %{state | task: task}}
  end

  def handle_info(:modules, state), do: {:noreply, state}

  def handle_info({ref, {modules, gave_up}}, %{task: %Task{ref: ref}} = state) do
    Process.demonitor(ref, [:flush])
    Process.send_after(self(), :modules, @modules_every)
    {:noreply, modules(modules, gave_up, %{state | task: nil})}
  end

  def handle_info({:DOWN, ref, :process, _, reason}, %{task: %Task{ref: ref}} = state) do
    Logger.warning("dashboard: listing the modules failed: #{inspect(reason)}")
    Process.send_after(self(), :modules, @modules_every)
    {:noreply, %{state | task: nil}}
  end

  def handle_info(_message, state), do: {:noreply, state}

  # restarts: a module seen under a new pid was restarted (modules are
  # told apart by robot and name: two robots may share a module name)
  defp modules(modules, gave_up, state) do
    restarts =
      Enum.reduce(modules, state.restarts, fn m, acc ->
        case state.pids[module_key(m)] do
          nil -> acc
          pid when pid == m.pid -> acc
          _other -> Map.update(acc, module_key(m), 1, &(&1 + 1))
        end
      end)

    payload = %{
      modules:
        for m <- modules do
          %{
            name: m.name,
            robot: m[:robot],
            module: inspect(m.module),
            node: m.node,
            activity: m.activity,
            layer: m[:layer],
            status: :running,
            pid: inspect(m.pid),
            started_at: m[:started_at],
            restarts: Map.get(restarts, module_key(m), 0)
          }
        end ++ given_up(gave_up, modules, restarts)
    }

    state = %{state | pids: Map.new(modules, &{module_key(&1), &1.pid}), restarts: restarts}

    if payload == state.modules,
      do: state,
      else: %{state | modules: payload, dirty: Map.put(state.dirty, "modules/all", payload)}
  end

  defp module_key(m), do: {m[:robot], m.name}

  # the modules of layers that gave up, and not running again: the one
  # that gave up, then those stopped with it
  defp given_up(gave_up, modules, restarts) do
    running = MapSet.new(modules, &module_key/1)

    rows =
      for Tuples.module_gave_up(robot, %{module: name} = g) <- gave_up,
          {status, stopped} <- [
            {:gave_up, name} | for(s <- List.wrap(g[:stopped]), s != name, do: {:stopped, s})
          ],
          stopped != nil,
          not MapSet.member?(running, {robot, stopped}) do
        %{
          name: stopped,
          robot: robot,
          module: nil,
          node: g[:node],
          activity: nil,
          layer: g[:layer],
          status: status,
          reason:
            if(status == :gave_up,
              do: gave_up_reason(g),
              else: "stopped with #{name || "its layer"}"
            ),
          pid: nil,
          started_at: nil,
          restarts: Map.get(restarts, {robot, stopped}, 0)
        }
      end

    Enum.uniq_by(rows, &{&1.robot, &1.name})
  end

  # the runtime's give-up says why and after how many restarts; a tuple
  # written by someone else may say less
  defp gave_up_reason(%{reason: reason, restarts: n, seconds: s}),
    do: "#{reason} (more than #{n} restarts in #{s} s)"

  defp gave_up_reason(g), do: "#{Map.get(g, :reason, "gave up")}"

  # ids are robot names (atoms) by convention, but any term may be there
  defp key(tag, id) when is_atom(id) or is_binary(id) or is_number(id), do: "#{tag}/#{id}"
  defp key(tag, id), do: "#{tag}/#{inspect(id)}"

  defp read_world(path) when is_binary(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, wdf} ->
        wdf

      {:error, errors} ->
        Logger.warning("dashboard: #{ThinkingCap.Config.format_errors(errors)}")
        nil
    end
  end

  defp read_world(other), do: other

  defp world(%ThinkingCap.Config.WDF{} = wdf) do
    wdf |> Map.from_struct() |> Map.delete(:file) |> JSON.encode!() |> IO.iodata_to_binary()
  end

  defp world(_other), do: "null"

  defp places(%ThinkingCap.Config.WDF{} = wdf),
    do: Enum.map(wdf.waypoints ++ wdf.rooms ++ wdf.corridors, &Atom.to_string(&1.name))

  defp places(_other), do: []
end
