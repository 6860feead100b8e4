defmodule ThinkingCap.Dashboard.Core.Yaws do
  @moduledoc false
  # Embedded yaws (Debian's erlang-yaws): one yaws instance serving two
  # servers, the dashboard (static files from its docroot, `/ws` for the
  # page's WebSocket) and the rosbridge endpoint (every path a WebSocket).
  # Debian installs yaws outside OTP's library directory, so its ebin is
  # put on the code path here. The `yaws` application is loaded, told it
  # is embedded (or it would look for /etc/yaws/yaws.conf), and never
  # started: its processes run under the dashboard's supervisor
  # (Core.WebServer), so the node stops them after its robots.

  alias ThinkingCap.Dashboard.Core.WebServer

  @id ~c"thinkingcap"
  @supervisor ThinkingCap.Dashboard.Supervisor

  @doc "Puts yaws on the code path; false if it is not installed."
  @spec ensure_available() :: boolean()
  def ensure_available do
    case Code.ensure_loaded(:yaws_api) do
      {:module, _} ->
        true

      _ ->
        Enum.each(Path.wildcard("/usr/lib/yaws-*/ebin"), &Code.prepend_path/1)
        match?({:module, _}, Code.ensure_loaded(:yaws_api))
    end
  end

  @doc """
  Starts yaws with `servers`, a list of `%{name, host, port, docroot,
  appmods: [{path, module}], opaque: keyword}`, and `limits`
  (`max_connections`, open connections at most; `idle_timeout`, ms a
  kept-alive connection may idle); returns the ports bound (a port 0 picks
  a free one).
  """
  @spec start([map()], map()) :: {:ok, %{atom() => :inet.port_number()}} | {:error, term()}
  def start(servers, limits \\ %{}) do
    with true <- ensure_available() || {:error, :yaws_not_installed},
         :ok <- load_yaws(),
         servers = bind_all(servers),
         {:ok, sc_groups, gc, child_specs} <-
           :yaws_api.embedded_start_conf(
             docroot(servers),
             Enum.map(servers, &sconf/1),
             gconf(limits),
             @id
           ),
         {:ok, _} <- start_server(child_specs, gc, sc_groups) do
      {:ok, Map.new(servers, &{&1.name, &1.port})}
    else
      {:error, reason} -> {:error, reason}
      other -> {:error, other}
    end
  end

  @doc "Stops yaws (its connections close, its ports are freed)."
  @spec stop() :: :ok
  def stop do
    with pid when is_pid(pid) <- WebServer.whereis() do
      _ = DynamicSupervisor.terminate_child(@supervisor, pid)
    end

    :ok
  end

  defp start_server(child_specs, gc, sc_groups) do
    DynamicSupervisor.start_child(@supervisor, {WebServer, {child_specs, gc, sc_groups}})
  end

  defp load_yaws do
    case Application.load(:yaws) do
      :ok -> :ok
      {:error, {:already_loaded, :yaws}} -> :ok
      error -> error
    end
    |> case do
      :ok ->
        Application.put_env(:yaws, :embedded, true)
        :ok

      error ->
        error
    end
  end

  # yaws binds as it starts, so a port 0 is replaced beforehand by a port
  # the OS reports free
  defp bind(%{port: 0} = server) do
    {:ok, socket} = :gen_tcp.listen(0, ip: ip(server.host), reuseaddr: true)
    {:ok, port} = :inet.port(socket)
    :gen_tcp.close(socket)
    %{server | port: port}
  end

  defp bind(server), do: server

  @doc "The servers as bound: each port 0 replaced by a free port."
  @spec bind_all([map()]) :: [map()]
  def bind_all(servers), do: Enum.map(servers, &bind/1)

  defp docroot([first | _]), do: to_charlist(first.docroot)

  defp sconf(server) do
    [
      port: server.port,
      servername: to_charlist("#{server.name}"),
      listen: ip(server.host),
      docroot: to_charlist(server.docroot),
      appmods: Enum.map(server.appmods, fn {path, mod} -> {to_charlist(path), mod} end),
      opaque: server |> Map.get(:opaque, []) |> Enum.to_list(),
      # yaws reads these only under flags: (a top-level access_log: false
      # is ignored, and every request, ?token= included, was logged)
      flags: [access_log: false, auth_log: false, deflate: false, dir_listings: false]
    ]
    |> Keyword.merge(Map.get(server, :yaws, []))
  end

  # yaws' own logs (its error report) go to the dashboard's private
  # runtime directory, wrapped at 1 MB
  defp gconf(limits) do
    [
      id: @id,
      logdir: to_charlist(ThinkingCap.Dashboard.Core.RuntimeDir.path()),
      log_wrap_size: 1_000_000,
      flags: [copy_errlog: false, log_resolve_hostname: false],
      max_connections: Map.get(limits, :max_connections, :nolimit),
      keepalive_timeout: Map.get(limits, :idle_timeout, 5_000)
    ]
  end

  @doc "The address of `host`, an IP address string."
  @spec ip(String.t()) :: :inet.ip_address()
  def ip(host) when is_binary(host) do
    case :inet.parse_address(to_charlist(host)) do
      {:ok, ip} -> ip
      {:error, _} -> raise ArgumentError, "dashboard host #{inspect(host)} is not an IP address"
    end
  end
end
