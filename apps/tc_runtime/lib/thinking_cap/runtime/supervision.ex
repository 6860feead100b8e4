defmodule ThinkingCap.Runtime.Supervision do
  @moduledoc """
  How a node supervises the modules it hosts: shaped like the robots, so
  that one robot's failure never takes another robot's modules.

      ThinkingCap.Runtime.Supervisor (rest_for_one)
      ├── :pg scope, ThinkingCap.Runtime.Registry, ThinkingCap.Cycle
      └── ThinkingCap.Runtime.Robots (DynamicSupervisor: a child per robot)
          └── robot r1 (one_for_one)
              ├── layer :reactive   (DynamicSupervisor, 5 restarts in 5 s)
              │   └── base, perception, control ...   (module hosts)
              ├── layer :cognitive  (DynamicSupervisor, 10 restarts in 60 s)
              │   └── localization, mapper, planner ...
              └── warden            (watches the two layers)

  ## Layers

  A module's layer is its ADF entry's `layer:`, or follows from its
  activity when the ADF does not say: `:periodic` modules are
  `:reactive`, `:event` and `:background` ones `:cognitive`.

    * `:reactive` - what stands between the sensors and the motors: the
      robot's base, perception, control. A crash is restarted at once
      (its periodic activity's fallback holds meanwhile), and a few are
      forgiven: **5 restarts in 5 s**. A module that crashes more often
      than that is not flaky but broken, and a robot driven by a control
      module that works one cycle in two must not drive on: the layer
      gives up within a second of a crash loop at a control rate.
    * `:cognitive` - localization, mapping, planning: slower, with
      heavier starts (maps, particles), and whose loss stops no motor by
      itself. **10 restarts in 60 s**: a bad reading that crashes a
      localizer now and then is ridden out; a module that cannot run is
      given up on within a minute.

  An operator's restart (`ThinkingCap.Runtime.restart/1`, the dashboard's
  button) stops the module and starts it again itself: it does not count
  against the layer's intensity, so no client can make a layer give up
  by asking for restarts.

  ## Giving up

  A layer whose modules exceed its restart intensity gives up: OTP's
  supervisor stops every module of that layer and exits. Nothing restarts
  it (its robot's supervisor holds it as a temporary child) and nothing
  else is touched: the robot's other layer, and every other robot's
  modules, run on with the same processes. The robot's **warden** then:

    * leaves the robot stopped, by the paths a stop always takes: the
      periodic activities of the layer's modules are removed from the
      timing worker, which applies each one's fallback at once (a wired
      base's stop bytes on its line), a robot base's `terminate/2` drives
      it to a stop, and the robot's E-stop is latched on the blackboard,
      `{:estop, robot, %{engaged: true, by: "runtime: module NAME gave
      up", at: ms}}`, as the dashboard, the console and the E-stop port
      latch it: a base wherever it runs (another node, the other layer)
      then applies `:stop` every cycle until an operator releases it;
    * says so on the blackboard: `{:module_gave_up, robot, %{module:
      name, layer:, node:, reason:, restarts:, seconds:, stopped: names,
      at: ms}}` (key `{:module_gave_up, robot, name}`), the module whose
      crash went over the limit and the modules stopped with it. The
      dashboard's Modules panel lists such a module as "gave up" with
      its reason.

  A layer that gave up stays down on that node: a deployment does not
  start its modules there again (nor, while that node is up, anywhere
  else), and `ThinkingCap.Runtime.start/1` refuses them, until
  `ThinkingCap.Runtime.resume/1` brings the layer back (a deployment
  then starts its modules again; the E-stop stays latched until
  released, an operator's decision).
  """

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Runtime.Supervision.{Robot, Warden}
  alias ThinkingCap.Tuples
  require Tuples

  @registry ThinkingCap.Runtime.Registry

  @typedoc "A supervision layer of a robot's modules."
  @type layer :: :reactive | :cognitive

  @layers [reactive: {5, 5}, cognitive: {10, 60}]

  @doc "The layers, with their restart intensities: `[layer: {max_restarts, max_seconds}]`."
  @spec layers() :: [{layer(), {pos_integer(), pos_integer()}}]
  def layers, do: @layers

  @doc "The layer names."
  @spec layer_names() :: [layer()]
  def layer_names, do: Keyword.keys(@layers)

  @doc """
  The layer of a module spec: its `layer:`, or by its activity
  (`:periodic` → `:reactive`, otherwise `:cognitive`).
  """
  @spec layer_of(map()) :: layer()
  def layer_of(spec) do
    case Map.get(spec, :layer) do
      layer when is_atom(layer) and layer != nil -> layer
      _ -> default_layer(Map.get(spec, :activity))
    end
  end

  @doc "The layer a module of `activity` is in when its ADF entry names none."
  @spec default_layer(atom()) :: layer()
  def default_layer(:periodic), do: :reactive
  def default_layer(_activity), do: :cognitive

  @doc false
  def registry, do: @registry

  @doc false
  def via(key), do: {:via, Registry, {@registry, key}}

  @doc false
  # the live process registered under `key` on this node, or nil
  def lookup(key) do
    case Registry.lookup(@registry, key) do
      [{pid, _}] -> if Process.alive?(pid), do: pid
      [] -> nil
    end
  end

  @doc """
  Starts a module host (`spec`, with `:robot`) under its robot's layer on
  this node, starting the robot's supervisor first if needed. A layer that
  gave up refuses: `{:error, {:layer_gave_up, robot, layer}}`.
  """
  @spec start_host(map()) :: {:ok, pid()} | {:error, term()}
  def start_host(spec) do
    layer = layer_of(spec)
    spec = Map.put(spec, :layer, layer)

    with {:ok, _robot_sup} <- ensure_robot(spec.robot) do
      case lookup({:layer, spec.robot, layer}) do
        nil ->
          {:error, {:layer_gave_up, spec.robot, layer}}

        sup ->
          case DynamicSupervisor.start_child(sup, {ThinkingCap.Runtime.Host, spec}) do
            {:ok, pid} -> {:ok, pid}
            {:error, {reason, _child}} -> {:error, reason}
            {:error, reason} -> {:error, reason}
          end
      end
    end
  end

  # the robot's supervisor on this node, started when its first module is
  defp ensure_robot(robot) do
    case lookup({:robot, robot}) do
      nil ->
        case DynamicSupervisor.start_child(ThinkingCap.Runtime.Robots, {Robot, robot}) do
          {:ok, pid} -> {:ok, pid}
          {:error, {:already_started, pid}} -> {:ok, pid}
          {:error, reason} -> {:error, {:robot_supervisor, robot, reason}}
        end

      pid ->
        {:ok, pid}
    end
  end

  @doc """
  Stops a module host of this node (its `terminate/2` runs); its
  supervisor does not start it again.
  """
  @spec terminate_host(pid()) :: :ok | {:error, :not_found}
  def terminate_host(pid) do
    case Process.info(pid, :parent) do
      {:parent, sup} when is_pid(sup) -> DynamicSupervisor.terminate_child(sup, pid)
      _ -> {:error, :not_found}
    end
  end

  @doc """
  Restarts module host `pid` of this node: it is stopped (its module's
  `terminate/2` gets `{:shutdown, :restart_requested}`) and started again
  from the spec it was started with, under the same layer. Not counted
  against the layer's restart intensity.
  """
  @spec restart_host(pid()) :: {:ok, pid()} | {:error, term()}
  def restart_host(pid) do
    with {:parent, sup} when is_pid(sup) <- Process.info(pid, :parent),
         {:dictionary, dictionary} <- Process.info(pid, :dictionary),
         {:ok, spec} <- Keyword.fetch(dictionary, :"$tc_spec") do
      try do
        :proc_lib.stop(pid, {:shutdown, :restart_requested}, 5_000)
      catch
        :exit, _ -> :ok
      end

      case DynamicSupervisor.start_child(sup, {ThinkingCap.Runtime.Host, spec}) do
        {:ok, pid} -> {:ok, pid}
        {:error, {reason, _child}} -> {:error, reason}
        {:error, reason} -> {:error, reason}
      end
    else
      _ -> {:error, :not_running}
    end
  end

  @doc """
  Whether `robot`'s layer `layer` gave up on this node (its robot's
  supervisor runs, the layer does not).
  """
  @spec gave_up?(atom(), layer()) :: boolean()
  def gave_up?(robot, layer),
    do: lookup({:robot, robot}) != nil and lookup({:layer, robot, layer}) == nil

  @doc """
  Brings back the layers of `robot` that gave up on this node and takes
  their `{:module_gave_up, ...}` tuples of this node off the blackboard.
  Returns the names of the modules that had given up or were stopped with
  them (a deployment starts them again; other callers start them).
  """
  @spec resume_here(atom()) :: [atom()]
  def resume_here(robot) do
    case lookup({:robot, robot}) do
      nil ->
        []

      sup ->
        for layer <- layer_names(),
            gave_up?(robot, layer),
            do: {:ok, _} = Supervisor.start_child(sup, Robot.layer_spec(robot, layer))

        Warden.resumed(robot)

        for Tuples.module_gave_up(^robot, %{node: node} = gave_up) <-
              Blackboard.rd_all(Tuples.module_gave_up(robot)),
            node == node(),
            {:ok, _} <- [Blackboard.takep(Tuples.module_gave_up(robot, gave_up))],
            name <- Enum.uniq([gave_up.module | gave_up.stopped]),
            name != nil,
            do: name
    end
  end
end
