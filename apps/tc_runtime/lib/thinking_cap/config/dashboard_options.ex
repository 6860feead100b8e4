defmodule ThinkingCap.Config.DashboardOptions do
  @port_or_nil {:or, [{:int_range, 0, 65_535}, {:one_of, [nil]}]}
  @string_or_nil {:or, [:string, {:one_of, [nil]}]}

  @fields [
    host: {:string, default: "127.0.0.1", doc: "the interface to bind (an IP address)"},
    port:
      {{:int_range, 0, 65_535},
       default: 4000, doc: "the page's HTTP and WebSocket port (0: any free port)"},
    rosbridge_port:
      {@port_or_nil,
       default: 9090, doc: "the rosbridge v2 endpoint's port (0: any free port, nil: none)"},
    foxglove_port:
      {@port_or_nil,
       default: nil,
       doc:
         "the Foxglove WebSocket endpoint's port (0: any free port, nil: none; Foxglove's usual one is 8765)"},
    public_view:
      {:boolean,
       default: false, doc: "let viewers without the access token watch (never control)"},
    token_file:
      {@string_or_nil,
       default: nil,
       doc:
         "a file holding the access token, readable by its owner only (default: a new random token)"},
    estop_port:
      {@port_or_nil,
       default: nil,
       doc:
         "a port apart from the web server that only engages E-stops (`curl -X POST HOST:PORT/estop`), reachable during a flood (0: any free port, nil: none)"},
    max_connections:
      {{:int_range, 1, 65_535},
       default: 512,
       doc:
         "open connections at most per listener (beyond: closed at once); lowered so that the listeners never take more than 3/4 of the node's file descriptors"},
    idle_timeout:
      {{:int_range, 100, 600_000},
       default: 5_000, doc: "ms a kept-alive HTTP connection may stay idle"},
    origins:
      {{:list, :string}, default: [], doc: "browser origins allowed besides the dashboard's own"},
    max_frame:
      {:pos_integer, default: 1_048_576, doc: "the largest WebSocket frame accepted, bytes"},
    send_timeout:
      {:pos_integer, default: 5_000, doc: "ms a browser may stop reading before it is dropped"},
    telemetry_hz:
      {:pos_integer, default: 25, doc: "telemetry frames per second at most, per browser"}
  ]

  @moduledoc """
  The web dashboard's options, defined once. The ADF's `dashboard:`
  section (`ThinkingCap.Config.ADF`) and `ThinkingCap.Dashboard.start/1`
  both validate them with these fields, in `ThinkingCap.Config.Schema`'s
  language: one set of keys, types, defaults and docs.

  The ADF adds the keys only a deployment needs (`enabled:`, `node:`);
  the dashboard adds those only a running dashboard takes (`token:`,
  `world:`, `static_dir:`).

  #{ThinkingCap.Config.Schema.describe(@fields)}
  """

  alias ThinkingCap.Config.Schema

  @doc "The fields, in `ThinkingCap.Config.Schema`'s language."
  @spec fields() :: Schema.fields()
  def fields, do: @fields

  @doc "The option names."
  @spec keys() :: [atom()]
  def keys, do: Keyword.keys(@fields)
end
