defmodule ThinkingCap.Dashboard.Core.Options do
  @moduledoc false
  # The dashboard's options, validated up front (unknown keys and wrong
  # types raise ArgumentError), with their defaults in one place.

  @options [
    host: {"127.0.0.1", "the interface to bind (an IP address)", :string?},
    port: {4000, "the page's HTTP and WebSocket port (0: any free port)", :port?},
    rosbridge_port:
      {9090, "the rosbridge v2 endpoint's port (0: any free port, nil: none)", :port_or_nil?},
    public_view: {false, "let viewers without the token watch (never control)", :boolean?},
    token: {nil, "the access token (default: a new random one)", :token?},
    token_file:
      {nil, "a file holding the access token (readable by its owner only)", :string_or_nil?},
    estop_port:
      {nil,
       "a port that only engages E-stops (`POST /estop`), apart from the web server " <>
         "(0: any free port, nil: none)", :port_or_nil?},
    max_connections:
      {512,
       "open connections at most per listener (beyond: closed at once); lowered so " <>
         "that the listeners never take more than 3/4 of the node's file descriptors", :pos_int?},
    idle_timeout: {5_000, "ms a kept-alive HTTP connection may stay idle", :pos_int?},
    origins: {[], "browser origins allowed besides the dashboard's own", :strings?},
    world: {nil, "the WDF shown on the map (a path or a ThinkingCap.Config.WDF)", :any?},
    max_frame: {1_048_576, "the largest WebSocket frame accepted, bytes", :pos_int?},
    send_timeout: {5_000, "ms a browser may stop reading before it is dropped", :pos_int?},
    telemetry_hz: {25, "telemetry frames per second at most, per browser", :pos_int?},
    static_dir: {nil, "the page's files (default: the app's priv/static)", :string_or_nil?}
  ]

  @doc "The options as documentation lines."
  @spec docs() :: String.t()
  def docs do
    Enum.map_join(@options, "\n", fn {key, {default, doc, _}} ->
      "  * `#{key}` - #{doc}; default `#{inspect(default)}`"
    end)
  end

  @doc "Validates `opts` and fills in the defaults; raises ArgumentError."
  @spec validate!(keyword() | map()) :: map()
  def validate!(opts) do
    opts = Enum.to_list(opts)

    for {key, value} <- opts do
      case Keyword.fetch(@options, key) do
        {:ok, {_, doc, valid?}} ->
          apply(__MODULE__, valid?, [value]) ||
            raise ArgumentError,
                  "dashboard option #{key}: #{inspect(value)} is not valid (#{doc})"

        :error ->
          raise ArgumentError,
                "unknown dashboard option #{inspect(key)}; known: " <>
                  Enum.map_join(Keyword.keys(@options), ", ", &inspect/1)
      end
    end

    config =
      Map.new(@options, fn {key, {default, _, _}} -> {key, Keyword.get(opts, key, default)} end)

    %{config | static_dir: config.static_dir || Application.app_dir(:tc_dashboard, "priv/static")}
  end

  @doc false
  def port?(p), do: is_integer(p) and p in 0..65_535
  @doc false
  def any?(_), do: true
  @doc false
  def string?(s), do: is_binary(s)
  @doc false
  def boolean?(b), do: is_boolean(b)
  @doc false
  def port_or_nil?(p), do: p == nil or port?(p)
  @doc false
  def pos_int?(n), do: is_integer(n) and n > 0
  @doc false
  def token?(t), do: t == nil or (is_binary(t) and byte_size(t) >= 8)
  @doc false
  def strings?(l), do: is_list(l) and Enum.all?(l, &is_binary/1)
  @doc false
  def string_or_nil?(s), do: s == nil or is_binary(s)
end
