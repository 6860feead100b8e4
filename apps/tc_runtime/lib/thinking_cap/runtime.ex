defmodule ThinkingCap.Runtime do
  @moduledoc """
  Hosts the modules an ADF names, each on the node the ADF assigns, and
  reports what runs where.

      {:ok, adf} = ThinkingCap.Config.read("priv/examples/office.adf")
      {:ok, started} = ThinkingCap.Runtime.start(adf)
      ThinkingCap.Runtime.which_modules()
      ThinkingCap.Runtime.swap(:control, MyRobot.BetterControl)   # while it runs
      ThinkingCap.Runtime.set_param(:control, :max_speed, 0.3)    # a live parameter
      ThinkingCap.Runtime.stop(:control)

  Each module runs in a process the framework owns
  (`ThinkingCap.Module`), supervised on its node under its robot and its
  layer (`ThinkingCap.Runtime.Supervision`): a module that crashes is
  restarted, and while it is down its periodic activity's fallback command
  holds (the timing worker applies it when the activity goes away). A
  module that keeps crashing makes its layer give up: that robot is left
  stopped and `{:module_gave_up, robot, ...}` says so, and no other
  robot's module is touched (`resume/1` brings the layer back). Module
  processes join a `:pg` group per module name, so every node can find
  every module.

  ## Scheduling of the BEAM side

  The control activity gets the CPU under load by three means:

    * the timing worker is a separate OS thread at `SCHED_FIFO` priority 80
      (when granted), so releases and fallbacks never wait for the BEAM;
    * the BEAM's normal scheduler threads and its I/O poller run at
      `SCHED_FIFO` priority 1, below the worker and with busy-waiting off
      (`ThinkingCap.Runtime.Scheduling` gives the reasons and the
      measurements), so OS-level load does not delay a cycle;
    * the cycle's owner process and periodic module processes run at
      process priority `:high`, event-driven ones at `:normal`, background
      ones at `:low` (they run only when nothing else is runnable);
    * a release that queued up behind a slow cycle is dropped in favour of
      the newest, so a late module catches up instead of falling further
      behind.
  """

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Config.ADF
  alias ThinkingCap.Runtime.Supervision
  alias ThinkingCap.Tuples
  require Tuples

  @scope :thinking_cap_runtime

  @doc false
  def scope, do: @scope

  @typedoc """
  A running module: its ADF name, or `{robot, name}` where two robots of
  the cluster run modules of the same name (a bare name then finds either).
  """
  @type module_ref :: atom() | {robot :: atom(), name :: atom()}

  @typedoc "A module as the runtime reports it."
  @type module_info :: %{
          name: atom(),
          robot: atom(),
          module: module(),
          node: node(),
          pid: pid(),
          activity: atom(),
          layer: Supervision.layer(),
          started_at: integer()
        }

  @doc """
  Starts every module of `adf` (a `ThinkingCap.Config.ADF` or the path of
  an ADF file) on its node. Returns what was started, or every module that
  could not be, with the reason. A started ADF is announced on the
  blackboard as `{:adf, robot, %{node:, file:, rdf:, wdf:, dashboard:,
  record:, black_box:, modules:}}` (the services that follow an ADF, such
  as the dashboard and the black box, start from it). Before the first
  module starts, the services that must be ready for it (the recorder)
  are told and waited for (`ThinkingCap.Runtime.Starting`).
  """
  @spec start(ADF.t() | Path.t()) :: {:ok, [module_info()]} | {:error, [{atom(), term()}]}
  def start(%ADF{} = adf) do
    # a recorder starts first: it records the modules from their init on
    :ok = prepare(adf, true)
    results = for spec <- adf.modules, do: {spec.name, start_module(adf, spec)}

    case for({name, {:error, reason}} <- results, do: {name, reason}) do
      [] ->
        announce(adf)
        {:ok, for({_name, {:ok, info}} <- results, do: info)}

      failed ->
        {:error, failed}
    end
  end

  def start(path) when is_binary(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, %ADF{} = adf} -> start(adf)
      {:ok, _other} -> {:error, [{:adf, "#{path} is not an ADF"}]}
      {:error, errors} -> {:error, [{:adf, ThinkingCap.Config.format_errors(errors)}]}
    end
  end

  @doc "Starts one module of `adf` (a module spec of `ThinkingCap.Config.ADF`) on its node."
  @spec start_module(ADF.t(), ADF.module_spec()) :: {:ok, module_info()} | {:error, term()}
  def start_module(%ADF{} = adf, spec) do
    node = node_of(adf, spec.node)
    spec = Map.merge(spec, %{robot: adf.robot, rdf: adf.rdf, wdf: adf.wdf})

    case :erpc.call(node, __MODULE__, :start_here, [spec], 15_000) do
      {:ok, pid} -> {:ok, info(pid)}
      {:error, reason} -> {:error, reason}
    end
  catch
    :error, {:erpc, reason} -> {:error, {:node_unreachable, node_of(adf, spec.node), reason}}
  end

  @doc false
  # Runs on the module's node.
  def start_here(spec) do
    with :ok <- check_module(spec.module),
         :ok <- start_application_of(spec.module),
         {:ok, pid} <- start_child(spec) do
      {:ok, pid}
    end
  end

  # the application a module belongs to runs before the module does (a
  # node that was started with the runtime alone, or a release booting)
  defp start_application_of(module) do
    with {:ok, app} <- :application.get_application(module),
         {:error, reason} <- Application.ensure_all_started(app) do
      {:error, {:application_not_started, app, reason}}
    else
      _ -> :ok
    end
  end

  defp start_child(spec), do: Supervision.start_host(spec)

  # A module must be loadable on its node and implement ThinkingCap.Module.
  defp check_module(module) do
    cond do
      not Code.ensure_loaded?(module) ->
        {:error, {:module_not_available, module, node()}}

      not function_exported?(module, :handle_cycle, 2) ->
        {:error, {:not_a_thinking_cap_module, module, "add `use ThinkingCap.Module`"}}

      true ->
        :ok
    end
  end

  @doc """
  Stops a module, wherever it runs, for good: its periodic activity is
  removed (the timing worker applies its fallback, on its wire too, and
  closes the wire). When it returns, the module's node no longer finds
  it; other nodes stop finding it as soon as `:pg` tells them.

  A module that died and is being restarted by its supervisor when this
  is called is stopped too, not left to come back: the process `:pg`
  still names may be the dead one, or none while the new one starts.
  """
  @spec stop(module_ref()) :: :ok | {:error, :not_running}
  def stop(name) do
    case whereis(name) || whereis_after_restarts(name) do
      nil ->
        {:error, :not_running}

      pid ->
        case :erpc.call(node(pid), __MODULE__, :stop_process_here, [name, pid]) do
          :ok -> :ok
          {:error, :not_found} -> {:error, :not_running}
        end
    end
  end

  # Between a dead module's exit and its restarted copy joining :pg, no
  # process is found by name; a layer supervisor answers only after a
  # restart it is doing, so a copy that is starting is found then.
  defp whereis_after_restarts(name) do
    sync_layers()
    whereis(name)
  end

  # waits until this node's layer supervisors have handled what they had
  defp sync_layers do
    ThinkingCap.Runtime.Supervision.registry()
    |> Registry.select([{{{:layer, :_, :_}, :"$1", :_}, [], [:"$1"]}])
    |> Enum.each(fn sup ->
      try do
        DynamicSupervisor.count_children(sup)
      catch
        :exit, _ -> :ok
      end
    end)
  end

  @doc false
  # Runs on the module's node: stops `pid`, module `ref`'s process, for
  # good. If it is no longer a supervisor's child, it died and its layer
  # has handled its exit (or is handling it): a copy it restarted runs
  # now, and is stopped in turn.
  @spec stop_process_here(module_ref(), pid()) :: :ok | {:error, :not_found}
  def stop_process_here(ref, pid) do
    case terminate_here(pid) do
      :ok ->
        :ok

      {:error, :not_found} ->
        sync_layers()

        case live_local_members(ref) -- [pid] do
          [] -> if Process.alive?(pid), do: {:error, :not_found}, else: :ok
          [other | _] -> stop_process_here(ref, other)
        end
    end
  end

  # :pg drops a dead process when it hears of its death, a little later
  defp live_local_members(ref),
    do: Enum.filter(:pg.get_local_members(@scope, group(ref)), &Process.alive?/1)

  @doc """
  Restarts a module, wherever it runs: it terminates (its `terminate/2`
  runs with `{:shutdown, :restart_requested}`, so a robot base leaves its
  robot stopped) and is started again on its node, under its layer, with
  the ADF's parameters. The periodic activity's fallback holds meanwhile.
  A restart asked for does not count against the layer's restart
  intensity (`ThinkingCap.Runtime.Supervision`): only crashes do.
  """
  @spec restart(module_ref()) :: :ok | {:error, :not_running | term()}
  def restart(name) do
    case whereis(name) do
      nil ->
        {:error, :not_running}

      pid ->
        case :erpc.call(node(pid), Supervision, :restart_host, [pid], 15_000) do
          {:ok, _pid} -> :ok
          {:error, reason} -> {:error, reason}
        end
    end
  end

  @doc """
  Replaces a running module's implementation in place (hot swap): the new
  module takes over the same process, periodic slot and subscriptions
  between two messages, so no release is missed.
  """
  @spec swap(module_ref(), module()) :: :ok | {:error, :not_running | term()}
  def swap(name, new_module) do
    case whereis(name) do
      nil ->
        {:error, :not_running}

      pid ->
        with :ok <- :erpc.call(node(pid), __MODULE__, :check_module_here, [new_module]),
             do: GenServer.call(pid, {:swap, new_module})
    end
  end

  @doc false
  def check_module_here(module), do: check_module(module)

  @doc """
  The process of a running module (on any node), or nil. A local process
  that died is not returned, though `:pg` may list it for a moment.
  """
  @spec whereis(module_ref()) :: pid() | nil
  def whereis(ref) do
    @scope
    |> :pg.get_members(group(ref))
    |> Enum.find(&(node(&1) != node() or Process.alive?(&1)))
  end

  @doc """
  Every process hosting module `ref`, on any node: more than one across a
  partition, or for a bare name that two robots use.
  """
  @spec whereis_all(module_ref()) :: [pid()]
  def whereis_all(ref), do: :pg.get_members(@scope, group(ref))

  @doc "The process of module `ref` on this node, or nil."
  @spec local_whereis(module_ref()) :: pid() | nil
  def local_whereis(ref) do
    case live_local_members(ref) do
      [pid | _] -> pid
      [] -> nil
    end
  end

  defp group({robot, name}) when is_atom(robot) and is_atom(name), do: {:module, robot, name}
  defp group(name) when is_atom(name), do: {:module, name}

  @doc "The modules running on this node: `[{name, pid}]`."
  @spec local_modules() :: [{atom(), pid()}]
  def local_modules do
    for {:module, name} = group when is_atom(name) <- :pg.which_groups(@scope),
        pid <- :pg.get_local_members(@scope, group),
        do: {name, pid}
  end

  @doc false
  # Stops module `ref` if it runs on this node.
  def stop_here(ref) do
    case live_local_members(ref) do
      [] -> :ok
      [pid | _] -> with {:error, :not_found} <- stop_process_here(ref, pid), do: :ok
    end
  end

  @doc false
  # Stops module host `pid` of this node for good (not restarted).
  def terminate_here(pid) do
    Supervision.Warden.stopping(pid)
    Supervision.terminate_host(pid)
  end

  @doc """
  Deploys `adf` (a path or a `ThinkingCap.Config.ADF`) on this node: starts
  its `ThinkingCap.Runtime.Deployment`, which connects to the ADF's other
  nodes and runs this node's share of its modules, with failover. Every
  node of the cluster deploys the same ADF. A release does this at boot
  when `TC_ADF` names an ADF.
  """
  @spec deploy(ADF.t() | Path.t()) :: {:ok, pid()} | {:error, term()}
  def deploy(adf) do
    case Supervisor.start_child(
           ThinkingCap.Runtime.Supervisor,
           {ThinkingCap.Runtime.Deployment, adf: adf}
         ) do
      {:ok, pid} -> {:ok, pid}
      {:error, {{:shutdown, message}, _child}} -> {:error, message}
      {:error, reason} -> {:error, reason}
    end
  end

  @doc """
  Brings back `robot`'s layers that gave up (`ThinkingCap.Runtime.Supervision`),
  on every connected node, and takes their `{:module_gave_up, ...}` tuples
  off the blackboard. A deployment then starts their modules again on its
  next round; modules started with `start/1` are started again by the
  caller (`start_module/2`). Returns the modules that had been stopped, by
  node. The robot's E-stop stays latched: releasing it is a separate,
  operator's decision.
  """
  @spec resume(atom()) :: %{node() => [atom()]}
  def resume(robot) do
    nodes = [node() | Node.list()]

    nodes
    |> :erpc.multicall(Supervision, :resume_here, [robot], 15_000)
    |> Enum.zip(nodes)
    |> Enum.flat_map(fn
      {{:ok, [_ | _] = names}, node} -> [{node, names}]
      _ -> []
    end)
    |> Map.new()
  end

  @doc "Every running module of the cluster: name, module, node, pid, activity, layer."
  @spec which_modules() :: [module_info()]
  def which_modules do
    @scope
    |> :pg.which_groups()
    |> Enum.flat_map(fn
      {:module, name} = group when is_atom(name) -> :pg.get_members(@scope, group)
      _robot_and_name -> []
    end)
    |> Enum.flat_map(fn pid ->
      try do
        [info(pid)]
      catch
        :exit, _ -> []
      end
    end)
    |> Enum.sort_by(& &1.name)
  end

  @typedoc """
  A running module's params as a user interface shows them
  (`describe_params/1`): whether it takes live changes, the current
  values, and each declared field with its type (`type`, as the ADF's
  tables name it), the kind of input that sets it (`input`: `:number`,
  `:integer`, `:boolean`, `:choice`, `:string`, or `:other`, not settable
  from a form), its bounds (`min`, `max`) or `choices`, `read_only`,
  `doc`, `default` and `value`.
  """
  @type params_info :: %{
          name: atom(),
          robot: atom(),
          module: module(),
          live: boolean(),
          values: map(),
          fields: [map()]
        }

  @doc """
  The params of a running module as they stand (live parameters, see
  `ThinkingCap.Module`): its declared fields with their defaults, and any
  change made since it started.
  """
  @spec get_params(module_ref()) :: {:ok, map()} | {:error, String.t()}
  def get_params(ref) do
    with {:ok, info} <- describe_params(ref), do: {:ok, info.values}
  end

  @doc "A running module's params with their schema, for user interfaces (`t:params_info/0`)."
  @spec describe_params(module_ref()) :: {:ok, params_info()} | {:error, String.t()}
  def describe_params(ref), do: call_module(ref, :params)

  @doc """
  Sets param `key` of running module `ref` to `value` (live parameters,
  see `ThinkingCap.Module`). The change is checked against the module's
  declared schema and handed to its `handle_param/3` before this returns,
  so a periodic module's next cycle runs with it; it is written to the
  blackboard as `{:param, robot, %{module:, key:, value:, by:, at:}}`.
  Otherwise `{:error, message}` says why not: no such module or param,
  the value out of range (the range) or of the wrong type (the type), a
  read-only param, a module that takes no live changes, or the module's
  own refusal. Options: `by:` who asks (shown on the blackboard; default
  `:api`).
  """
  @spec set_param(module_ref(), atom(), term(), keyword()) :: :ok | {:error, String.t()}
  def set_param(ref, key, value, opts \\ []),
    do: call_module(ref, {:set_param, key, value, Keyword.get(opts, :by, :api)})

  defp call_module(ref, request) do
    case whereis(ref) do
      nil ->
        {:error, "no module #{inspect(ref)} is running"}

      pid ->
        try do
          case GenServer.call(pid, request, 5_000) do
            {:error, message} -> {:error, message}
            :ok -> :ok
            info -> {:ok, info}
          end
        catch
          :exit, reason ->
            {:error, "module #{inspect(ref)} did not answer: #{Exception.format_exit(reason)}"}
        end
    end
  end

  @doc "Timing statistics of this node's periodic activities (`ThinkingCap.Cycle.timing/0`)."
  @spec timing() :: %{atom() => map()}
  def timing, do: ThinkingCap.Cycle.timing()

  defp info(pid), do: GenServer.call(pid, :info)

  @doc false
  # Before a node starts the first of `adf`'s modules: the services that
  # must be ready (the recorder) are told and waited for, on the node that
  # announces the ADF (its dashboard's); on the others, with recording
  # on, until the robot's recorder is attached, wherever it runs (at most
  # 5 s): their modules are traced from their init too.
  @spec prepare(ADF.t(), boolean()) :: :ok
  def prepare(%ADF{} = adf, announcing?) do
    cond do
      announcing? ->
        ThinkingCap.Runtime.Starting.notify(adf.robot, announcement(adf))

      adf.record[:enabled] == true ->
        await_sink(adf.robot, System.monotonic_time(:millisecond) + 5_000)

      true ->
        :ok
    end
  end

  defp await_sink(robot, deadline) do
    cond do
      ThinkingCap.Runtime.Trace.sinks(robot) != [] -> :ok
      System.monotonic_time(:millisecond) >= deadline -> :ok
      true -> Process.sleep(20) && await_sink(robot, deadline)
    end
  end

  @doc false
  # What was started, for the services that follow an ADF (the dashboard
  # starts itself on the announcing node when the ADF enables it)
  def announce(%ADF{} = adf) do
    {tuple, opts} = Tuples.keyed(Tuples.adf(adf.robot, announcement(adf)))
    Blackboard.out(tuple, opts)
  end

  defp announcement(adf) do
    %{
      node: node(),
      file: adf.file,
      rdf: adf.rdf,
      wdf: adf.wdf,
      dashboard: adf.dashboard,
      record: adf.record,
      black_box: adf.black_box,
      modules: Enum.map(adf.modules, & &1.name)
    }
  end

  defp node_of(_adf, :local), do: node()
  defp node_of(%ADF{nodes: nodes}, logical), do: Map.fetch!(nodes, logical)
end
