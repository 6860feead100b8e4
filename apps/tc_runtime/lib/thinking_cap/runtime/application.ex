defmodule ThinkingCap.Runtime.Application do
  @moduledoc false
  # The execution layer's supervision tree (rest_for_one: later children
  # depend on earlier ones):
  #
  #   :pg scope                  finds every node's modules
  #   ThinkingCap.Runtime.Registry  names of robots' supervisors, layers, wardens
  #   ThinkingCap.Cycle          the timing worker's owner
  #   ThinkingCap.Runtime.Robots   DynamicSupervisor: a supervisor per robot,
  #                                a layer supervisor per layer inside it
  #                                (ThinkingCap.Runtime.Supervision)
  #   (a release's boot deployment, when `config :tc_runtime, deploy: adf`)
  #
  # A release deploys its ADF once the whole release has booted (the
  # modules an ADF names live in later applications), from a task that
  # logs a bad ADF instead of failing the boot: the node stays up for a
  # remote shell.
  # One crash-looping module must not take other robots' modules down:
  # restart intensities are per robot and layer, below Robots, whose
  # children (robots' supervisors) are temporary and never restarted, so
  # Robots itself never exceeds its intensity.
  use Application
  require Logger

  @impl true
  def start(_type, _args) do
    ThinkingCap.Runtime.Scheduling.apply_config()
    # SIGTERM stops the robots before the node (ThinkingCap.Runtime.Shutdown)
    :ok = ThinkingCap.Runtime.Shutdown.install()

    children = [
      %{id: :pg, start: {:pg, :start_link, [ThinkingCap.Runtime.scope()]}},
      {Registry, keys: :unique, name: ThinkingCap.Runtime.Supervision.registry()},
      ThinkingCap.Cycle,
      {DynamicSupervisor, name: ThinkingCap.Runtime.Robots, strategy: :one_for_one}
    ]

    boot =
      case Application.get_env(:tc_runtime, :deploy) do
        nil ->
          []

        adf ->
          [Supervisor.child_spec({Task, fn -> deploy_after_boot(adf) end}, restart: :temporary)]
      end

    Supervisor.start_link(children ++ boot,
      strategy: :rest_for_one,
      name: ThinkingCap.Runtime.Supervisor
    )
  end

  # Stopping, the robots stop first (Shutdown.begin/1, a no-op when an
  # application above already called it), then the BEAM's threads go back
  # to normal scheduling before the VM halts:
  # while it shuts down, a scheduler at SCHED_FIFO spins waiting on
  # threads at normal priority, which it then keeps off the CPU (seen on
  # peer nodes: a stop that never ended, a core at 100 %).
  @impl true
  def prep_stop(state) do
    # the robots stop first, if no application above did it already
    ThinkingCap.Runtime.Shutdown.begin()

    if Application.get_env(:tc_runtime, :beam_priority, :realtime) != nil,
      do: ThinkingCap.Runtime.Scheduling.nice(0)

    state
  end

  defp deploy_after_boot(adf) do
    wait_for_boot()

    case ThinkingCap.Runtime.deploy(adf) do
      {:ok, _pid} -> :ok
      {:error, message} -> Logger.error("could not deploy #{adf}: #{message}")
    end
  end

  defp wait_for_boot do
    case :init.get_status() do
      {:started, _} ->
        :ok

      _ ->
        Process.sleep(50)
        wait_for_boot()
    end
  end
end
