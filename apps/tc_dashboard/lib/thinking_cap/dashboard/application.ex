defmodule ThinkingCap.Dashboard.Application do
  @moduledoc false
  # Supervision: ThinkingCap.Dashboard.Root (one_for_one) holds
  #   * Dashboard.Sockets, a registry of the open WebSockets (yaws owns
  #     their processes; the registry lets stop/0 close them),
  #   * Dashboard.Supervisor, a DynamicSupervisor for a running dashboard's
  #     telemetry collector, its web server's watchdog (Core.Watchdog) and
  #     its E-stop port (Core.EstopListener), started by
  #     ThinkingCap.Dashboard.start/1,
  #   * Dashboard.Timelines, a DynamicSupervisor of the open black-box
  #     timelines (Dashboard.Timeline), at most Timeline.max_open/0,
  #   * Core.RestartLimit, how often clients may restart modules,
  #   * Dashboard.Launcher, which starts the dashboard when an ADF that
  #     enables it starts on this node.
  # yaws is loaded, not started as an application: its processes run
  # under Dashboard.Supervisor (Core.WebServer), so they stop with the
  # dashboard, after the robots.
  use Application

  @impl true
  def start(_type, _args) do
    ThinkingCap.Dashboard.Core.LogLimit.install()

    children = [
      {Registry, keys: :duplicate, name: ThinkingCap.Dashboard.Sockets},
      {DynamicSupervisor, name: ThinkingCap.Dashboard.Supervisor, strategy: :one_for_one},
      {DynamicSupervisor,
       name: ThinkingCap.Dashboard.Timelines,
       strategy: :one_for_one,
       max_children: ThinkingCap.Dashboard.Timeline.max_open()},
      ThinkingCap.Dashboard.Core.RestartLimit,
      ThinkingCap.Dashboard.Launcher
    ]

    Supervisor.start_link(children, strategy: :one_for_one, name: ThinkingCap.Dashboard.Root)
  end

  # The top application, the first the node stops: the robots stop first
  # (ThinkingCap.Runtime.Shutdown), then the dashboard closes its sockets
  # and its web server.
  @impl true
  def prep_stop(state) do
    ThinkingCap.Runtime.Shutdown.begin()
    ThinkingCap.Dashboard.stop()
    state
  end
end
