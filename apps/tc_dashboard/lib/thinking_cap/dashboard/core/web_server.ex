defmodule ThinkingCap.Dashboard.Core.WebServer do
  @moduledoc false
  # yaws' processes, under the dashboard's own supervision tree rather
  # than as the `yaws` application. An application started at run time is
  # the first the node stops, before the dashboard's `prep_stop` has
  # stopped the robots: the robot drove on while yaws took 2 s to close.
  # Here yaws stops with the dashboard, after the robots.
  #
  # The children are those yaws' embedded start gives
  # (`:yaws_api.embedded_start_conf/4`), then a last one that hands yaws
  # its configuration (`:yaws_api.setconf/2`) and ends. yaws' own
  # supervisor never restarts them ("the supervisor above us wants to
  # control the restarts"); neither does this one: when one dies the
  # whole server stops, for good (a temporary child), and Core.Watchdog
  # starts it again, configured.

  use Supervisor, restart: :temporary

  @doc "Starts the server from yaws' child specs, its global and its server configurations."
  @spec start_link({[Supervisor.child_spec() | tuple()], tuple(), list()}) ::
          Supervisor.on_start()
  def start_link({child_specs, gconf, sconf_groups}) do
    Supervisor.start_link(__MODULE__, {child_specs, gconf, sconf_groups}, name: __MODULE__)
  end

  @doc "The running server's pid, or nil."
  @spec whereis() :: pid() | nil
  def whereis, do: Process.whereis(__MODULE__)

  @impl true
  def init({child_specs, gconf, sconf_groups}) do
    configure = %{
      id: :setconf,
      start: {__MODULE__, :configure, [gconf, sconf_groups]},
      restart: :transient
    }

    Supervisor.init(child_specs ++ [configure], strategy: :one_for_all, max_restarts: 0)
  end

  @doc false
  # yaws binds its ports here; the child ends once it has.
  def configure(gconf, sconf_groups) do
    case :yaws_api.setconf(gconf, sconf_groups) do
      :ok -> :ignore
      {:error, reason} -> {:error, reason}
      other -> {:error, other}
    end
  end
end
