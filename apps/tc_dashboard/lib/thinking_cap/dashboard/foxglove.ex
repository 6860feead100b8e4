defmodule ThinkingCap.Dashboard.Foxglove do
  @moduledoc """
  The Foxglove WebSocket endpoint: the robots' scans, maps and poses live
  in [Foxglove](https://foxglove.dev) ("Open connection" → "Foxglove
  WebSocket"), with the same topics and schemas as a recording of the
  black box (`ThinkingCap.BlackBox.Foxglove`).

  It listens on its own port, the dashboard's `foxglove_port` (none by
  default; Foxglove's usual port is 8765, which the example ADF uses, and
  `bin/run --foxglove-port P` moves it). Every path of
  `ws://HOST:PORT/?token=TOKEN` is a WebSocket speaking the
  [Foxglove WebSocket protocol](https://github.com/foxglove/ws-protocol)
  under either subprotocol name, `foxglove.websocket.v1` or
  `foxglove.sdk.v1` (the client's first choice of the two is answered).

  ## Channels

  On connecting a client gets `serverInfo` (no capabilities, encoding
  `json`), then one `advertise` per robot that published its capabilities
  (`{:robot, r1, caps}`):

  | topic | schema | from |
  |---|---|---|
  | `/r1/laser` (one per laser sensor, by its name) | `foxglove.LaserScan` | the sensor's readings |
  | `/r1/map` | `foxglove.Grid` | `{:map, r1, grid}`, the map the robot learned |
  | `/r1/pose` | `foxglove.PoseInFrame` | `{:pose, r1, estimate}`, the localizer's estimate in `map` |
  | `/r1/tf` | `foxglove.FrameTransform` | the same estimate, `map` → `r1/base_link` |

  Messages are JSON with their JSON schema (`schemaEncoding:
  "jsonschema"`). Robots that appear later are advertised when they do;
  a robot whose `{:robot, ...}` tuple is gone is unadvertised within a
  second.

  ## Operations

  `subscribe` (`subscriptions: [{id, channelId}]`, the ids the client's)
  sends the channel's newest message at once (the streams are
  latest-value tuples), then each new one, as a binary `messageData`
  frame: opcode 1, the subscription id (uint32, little-endian), the
  message's time in nanoseconds (uint64, little-endian; the payload's
  `stamp` on the robot's clock, else the wall clock) and the JSON.
  `unsubscribe` (`subscriptionIds`) stops them. Every other operation,
  and every malformed message, gets a `status` error (level 2) and
  changes nothing; 256 subscriptions at most.

  Bounds: frames from the client over the dashboard's `max_frame` close
  the connection (1009); messages over the dashboard's rate budget are
  dropped, a flood closes it (1008); a client that stops reading for
  `send_timeout` ms is dropped; a slow client gets fewer messages (the
  blackboard drops what its mailbox cannot hold), never slowing a robot.
  A message over 16 MB is not sent (a status warning says so).

  ## Access

  The endpoint only shows: it offers no publishing, parameters or
  services. Even so it needs the dashboard's access token in the URL
  (`?token=`): without it the upgrade is refused (401) and nothing is
  sent, unless the dashboard's `public_view` is on, which lets viewers
  in as it does on the page. Browsers (the Foxglove web app) must come
  from an origin the dashboard allows (its own or one in `origins`, such
  as `https://app.foxglove.dev`); clients without an Origin (Foxglove
  desktop, Node, Python) pass.

  The endpoint runs its own small WebSocket server rather than yaws:
  yaws 2.1 does not answer the client's `Sec-WebSocket-Protocol`, and
  Foxglove's clients refuse a handshake that does not name their
  subprotocol.
  """

  alias ThinkingCap.Dashboard.Foxglove.Handshake

  @doc "The subprotocol names the endpoint accepts."
  @spec subprotocols() :: [String.t()]
  def subprotocols, do: Handshake.subprotocols()

  @doc "The endpoint's URL, with the token, for a dashboard `info` (nil without the endpoint)."
  @spec url(map()) :: String.t() | nil
  def url(%{foxglove_port: port, host: host, token: token}) when is_integer(port),
    do: "ws://#{url_host(host)}:#{port}/?token=#{token}"

  def url(_info), do: nil

  defp url_host("0.0.0.0"), do: "127.0.0.1"
  defp url_host(host), do: if(String.contains?(host, ":"), do: "[#{host}]", else: host)
end
