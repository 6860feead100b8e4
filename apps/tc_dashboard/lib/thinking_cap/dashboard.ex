defmodule ThinkingCap.Dashboard do
  @moduledoc """
  The web dashboard: live monitoring and teleoperation in the browser, and
  a rosbridge v2 endpoint for the tools robotics engineers already use
  (roslibjs apps, Foxglove), and a Foxglove WebSocket endpoint
  (`ThinkingCap.Dashboard.Foxglove`, on its own port when
  `foxglove_port` is set).

  It runs embedded yaws (Debian `erlang-yaws`) with two servers: the page
  (`http://HOST:PORT/`, its static files, and `/ws`, the WebSocket of
  `ThinkingCap.Dashboard.Session`, see `PROTOCOL.md`) and the rosbridge
  endpoint (`ws://HOST:ROSBRIDGE_PORT/`, `ThinkingCap.Dashboard.Rosbridge`).
  Telemetry is collected once per node by `ThinkingCap.Dashboard.Telemetry`
  and each browser pulls what changed at its own pace, so a slow or stalled
  browser gets fewer frames (and is dropped after 5 s of not reading); it
  never slows the blackboard or the control cycle.

  An ADF turns it on (`dashboard: [enabled: true, port: 4000]`): when
  `ThinkingCap.Runtime` starts that ADF on this node, the dashboard starts
  with it (`info/0` then tells where). It can also be started by hand:

      {:ok, %{url: url}} = ThinkingCap.Dashboard.start(port: 4000)

  ## Access
  Controlling actions (teleoperation, goals, releasing an E-stop,
  restarting a module, publishing `/cmd_vel`) need the access token, a
  random string made at start and printed in the URL (as notebook servers
  do), or read from `token_file` (a file its owner alone may read). It is
  compared in constant time and never written to a log: yaws' access log
  is off, and its own logs go to a directory of mode 0700 of the
  dashboard's (`$XDG_RUNTIME_DIR` or the system's temporary directory),
  removed when the dashboard stops. Without it the page's socket (all
  data and actions) is refused, unless `public_view: true` lets viewers
  watch (never control); the page's static files hold nothing of the
  robot and are served to anyone. Engaging an E-stop needs no token: anyone
  who sees the robot may stop it. Browsers must come from the dashboard's
  own origin or one listed in `origins`.

  ## Options
  #{ThinkingCap.Dashboard.Core.Options.docs()}
  """

  alias ThinkingCap.Dashboard.Core
  alias ThinkingCap.Dashboard.Core.{Access, Options, Yaws}

  @config {__MODULE__, :config}

  @type info :: %{
          url: String.t(),
          token: String.t(),
          host: String.t(),
          port: :inet.port_number(),
          rosbridge_port: :inet.port_number() | nil,
          foxglove_port: :inet.port_number() | nil,
          estop_port: :inet.port_number() | nil
        }

  @doc """
  Starts the dashboard (see the options above). Returns where it listens and
  its access token.
  """
  @spec start(keyword()) :: {:ok, info()} | {:error, term()}
  def start(opts \\ []) do
    opts = Options.validate!(opts)

    if config() do
      {:error, {:already_started, info()}}
    else
      with {:ok, token} <- token(opts) do
        do_start(Map.put(opts, :token, token))
      end
    end
  end

  defp do_start(config) do
    servers =
      [
        %{
          name: :page,
          host: config.host,
          port: config.port,
          docroot: config.static_dir,
          appmods: [
            {"/ws", ThinkingCap.Dashboard.Core.Appmod},
            {"/dumps", ThinkingCap.Dashboard.Core.Download}
          ],
          opaque: [handler: ThinkingCap.Dashboard.Session, view_needs_token: true]
        }
      ] ++
        if config.rosbridge_port do
          [
            %{
              name: :rosbridge,
              host: config.host,
              port: config.rosbridge_port,
              docroot: config.static_dir,
              appmods: [{"/", ThinkingCap.Dashboard.Core.Appmod}],
              opaque: [handler: ThinkingCap.Dashboard.Rosbridge.Session, view_needs_token: false]
            }
          ]
        else
          []
        end

    # the appmods read the configuration: it is there before a port opens
    :persistent_term.put(@config, Map.put(config, :ready, false))

    servers = Yaws.bind_all(servers)

    limits = %{
      max_connections: max_connections(config, length(servers)),
      idle_timeout: config.idle_timeout
    }

    with {:ok, _} <- start_telemetry(config),
         {:ok, ports} <- Yaws.start(servers, limits),
         {:ok, _} <- start_child({ThinkingCap.Dashboard.Core.Watchdog, {servers, limits}}),
         {:ok, foxglove} <- start_foxglove(%{config | max_connections: limits.max_connections}),
         {:ok, estop} <- start_estop(config) do
      config =
        Map.merge(config, %{
          port: ports.page,
          rosbridge_port: ports[:rosbridge],
          foxglove_port: foxglove && ThinkingCap.Dashboard.Foxglove.Listener.port(),
          estop_port: estop && ThinkingCap.Dashboard.Core.EstopListener.port(),
          ready: true
        })

      :persistent_term.put(@config, config)
      {:ok, info()}
    else
      error ->
        stop()
        error
    end
  end

  @doc """
  Stops the dashboard (its servers and its telemetry) and removes its
  runtime files.
  """
  @spec stop() :: :ok
  def stop do
    # the watchdog first, or it would start the web server again; the web
    # server last, once the sockets are closed
    {watchdogs, others} =
      ThinkingCap.Dashboard.Supervisor
      |> DynamicSupervisor.which_children()
      |> Enum.reject(fn {_, _, _, modules} -> modules == [Core.WebServer] end)
      |> Enum.split_with(fn {_, _, _, modules} -> modules == [Core.Watchdog] end)

    for {_, pid, _, _} <- watchdogs ++ others,
        do: DynamicSupervisor.terminate_child(ThinkingCap.Dashboard.Supervisor, pid)

    ThinkingCap.Dashboard.Core.Socket.close_all()
    Yaws.stop()
    ThinkingCap.Dashboard.Core.RuntimeDir.remove()

    :persistent_term.erase(@config)
    :ok
  end

  @doc "Where the running dashboard listens, with its token; nil when it is not running."
  @spec info() :: info() | nil
  def info do
    case config() do
      %{ready: true} = c ->
        %{
          url: "http://#{url_host(c.host)}:#{c.port}/?token=#{c.token}",
          token: c.token,
          host: c.host,
          port: c.port,
          rosbridge_port: c.rosbridge_port,
          foxglove_port: c.foxglove_port,
          estop_port: c.estop_port
        }

      _starting_or_stopped ->
        nil
    end
  end

  @doc "Waits up to `timeout` ms for the dashboard to be running (an ADF starts it asynchronously)."
  @spec await(timeout()) :: {:ok, info()} | {:error, :timeout}
  def await(timeout \\ 5_000) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      info() || (System.monotonic_time(:millisecond) < deadline && Process.sleep(20))
    end)
    |> Enum.find(&(is_map(&1) or &1 == false))
    |> case do
      %{} = info -> {:ok, info}
      false -> {:error, :timeout}
    end
  end

  @doc false
  # the running configuration (the validated options and the token)
  @spec config() :: map() | nil
  def config, do: :persistent_term.get(@config, nil)

  # the token given, read from its file, or a new one
  defp token(%{token_file: path}) when is_binary(path) do
    with {:ok, %{mode: mode}} <- File.stat(path),
         0 <- Bitwise.band(mode, 0o077),
         {:ok, text} <- File.read(path),
         token when byte_size(token) >= 8 <- String.trim(text) do
      {:ok, token}
    else
      {:error, reason} ->
        {:error, "token file #{path}: #{:file.format_error(reason)}"}

      bits when is_integer(bits) ->
        {:error,
         "token file #{path} is readable by others (mode #{Integer.to_string(bits, 8)} " <>
           "beyond the owner's): chmod 600 it"}

      _short ->
        {:error, "token file #{path}: the token must be at least 8 characters"}
    end
  end

  defp token(opts), do: {:ok, opts.token || Access.new_token()}

  defp start_telemetry(config), do: start_child({ThinkingCap.Dashboard.Telemetry, config})

  defp start_foxglove(%{foxglove_port: nil}), do: {:ok, nil}

  defp start_foxglove(config),
    do: start_child({ThinkingCap.Dashboard.Foxglove.Listener, config})

  defp start_estop(%{estop_port: nil}), do: {:ok, nil}

  defp start_estop(config),
    do:
      start_child(
        {ThinkingCap.Dashboard.Core.EstopListener, Map.take(config, [:host, :estop_port])}
      )

  defp start_child(spec),
    do: DynamicSupervisor.start_child(ThinkingCap.Dashboard.Supervisor, spec)

  # connections per listener: the option, but never so many that the
  # listeners together could take the node's last file descriptors (yaws
  # exits when accept fails for want of one); a quarter of them is kept
  # for the rest of the node (code loading, serial lines, the timing worker)
  defp max_connections(config, listeners) do
    fds =
      :erlang.system_info(:check_io)
      |> List.wrap()
      |> List.flatten()
      |> Enum.find_value(65_536, fn
        {:max_fds, n} when is_integer(n) -> n
        _ -> nil
      end)

    budget = max(div(div(fds * 3, 4) - 64, listeners), 16)
    min(config.max_connections, budget)
  end

  defp url_host("0.0.0.0"), do: "127.0.0.1"
  defp url_host(host), do: if(String.contains?(host, ":"), do: "[#{host}]", else: host)
end
