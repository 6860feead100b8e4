defmodule ThinkingCap.Dashboard.Rosbridge do
  @moduledoc """
  The rosbridge v2 endpoint: the blackboard's robot streams as ROS 2
  topics, for the tools robotics engineers already use (roslibjs apps,
  Foxglove's Rosbridge connection, webviz-like pages).

  It listens on its own port (the dashboard's `rosbridge_port`, default
  9090): every path of `ws://HOST:PORT/` is a WebSocket speaking the
  [rosbridge v2 protocol](https://github.com/RobotWebTools/rosbridge_suite/blob/ros2/ROSBRIDGE_PROTOCOL.md)
  as JSON text frames. Each connection is served by
  `ThinkingCap.Dashboard.Rosbridge.Session` behind the dashboard's socket
  (frame size limit, message-rate budget, send timeout).

  ## Topics

  Every robot that published its capabilities (`{:robot, r1, caps}`)
  appears under its own namespace:

  | topic | type | from |
  |---|---|---|
  | `/r1/scan` | `sensor_msgs/msg/LaserScan` | `{:laser, r1, ...}` (the robot's first laser sensor; frame `r1/laser`) |
  | `/r1/odom` | `nav_msgs/msg/Odometry` | `{:odom, r1, ...}` (its odometry sensor; frame `r1/odom`, child `r1/base_link`) |
  | `/r1/pose`, `/r1/amcl_pose` | `geometry_msgs/msg/PoseWithCovarianceStamped` | `{:pose, r1, ...}`, the localizer's estimate (frame `map`) |
  | `/r1/map` | `nav_msgs/msg/OccupancyGrid` | `{:map, r1, ...}`, the map the robot learned (`ThinkingCap.Navigation.Mapper`; frame `map`), each new version |
  | `/r1/cmd_vel` | `geometry_msgs/msg/Twist` | published by clients: teleoperation (see below); subscribing shows the command the base applies (`{:control, r1, ...}`) |
  | `/r1/tf`, `/r1/tf_static` | `tf2_msgs/msg/TFMessage` | that robot's part of `/tf` and `/tf_static` |
  | `/tf` | `tf2_msgs/msg/TFMessage` | every robot's `map → r1/odom` and `r1/odom → r1/base_link` |
  | `/tf_static` | `tf2_msgs/msg/TFMessage` | every robot's `r1/base_link → r1/<sensor>`, for each sensor with a pose |
  | `/map` | `nav_msgs/msg/OccupancyGrid` | the maps the robots learned, else the dashboard's world (frame `map`) |

  `map → r1/odom` is what places the odometry frame in the map: the
  localizer's estimate composed with the inverse of the odometry pose
  (both the newest ones), identity while there is no estimate. `/map`
  carries every new version of a map a robot learned, and the newest at
  once when subscribed; without one, the WDF's imported ROS map as it is
  or its walls, obstacles and closed doors rasterized at 5 cm (occupied
  100, free 0), sent once when subscribed (a latched topic).

  **Namespaces.** Robot topics are always namespaced (`/r1/scan`), so
  adding a second robot never renames a topic. While exactly one robot is
  known, `/scan`, `/odom`, `/pose`, `/amcl_pose` and `/cmd_vel` are also served as
  aliases of its topics (the names single-robot ROS tools default to),
  resolved when subscribed or advertised: they keep naming that robot.
  With several robots they are refused as ambiguous. Frame ids are always
  namespaced (`r1/odom`), and `/tf`, `/tf_static` and `/map` are global
  (one world, one `map` frame). A robot's topic may be subscribed before
  the robot appears: its messages come once it does.

  **ROS 2.** Messages have ROS 2 shapes (`header.stamp` is `{sec,
  nanosec}`, types are named `pkg/msg/Type`; `pkg/Type` is accepted from
  clients), and `/rosapi/get_ros_version` answers `{version: 2, distro:
  "humble"}`, so clients pick their ROS 2 parsing. Stamps are the
  payloads' own (simulated seconds for a simulated robot).

  ## Operations

    * `subscribe` (`topic`, optional `type` checked against the topic's,
      `throttle_rate` in ms, `id`) sends the topic's latest value at once
      (the streams are latest-value tuples), then each new one.
      `throttle_rate` is the shortest interval between two messages of one
      robot on the topic: in between, only the newest is kept and sent when
      the interval is over (`queue_length` is always 1). Subscriptions with
      different ids to one topic share it: the smallest throttle applies,
      and `unsubscribe` with an id removes that one (without, all of them).
    * `advertise` / `unadvertise` / `publish`: only `cmd_vel` topics can be
      published. A `publish` on `/r1/cmd_vel` is teleoperation
      (`ThinkingCap.Dashboard.Control.teleop/4`: `linear.x` and
      `angular.z`, clamped to the robot's limits) under the same deadman
      rule as the page's: the robot stops 300 ms after the last message,
      so publish at 10 Hz or more while driving. `unadvertise` and closing
      the connection hand the robot back at once.
    * `call_service`, answered with `service_response` (`result: false`
      and an error text in `values` for an unknown service or bad
      arguments): `/rosapi/topics`, `/rosapi/topics_for_type`,
      `/rosapi/topic_type`, `/rosapi/topics_and_raw_types` (with ROS 2
      message definitions, which Foxglove uses to parse),
      `/rosapi/services`, `/rosapi/service_type`, `/rosapi/nodes`,
      `/rosapi/get_ros_version`, `/rosapi/get_time`. Clients cannot
      advertise services (`advertise_service` and a client's
      `service_response` are refused).
    * `status`: every refused message gets
      `{"op":"status","level":"error","msg":...,"id":...}` (its id echoed)
      and changes nothing; `set_level` (`info`, `warning`, `error`,
      `none`; default `error`) chooses which statuses are sent.
    * `auth` (`{"op":"auth","mac":TOKEN,...}`): see Access.

  Not supported: fragmentation (`fragment_size` is ignored: messages are
  sent whole) and compression (`png`, `cbor`: messages are sent as JSON
  text, with a warning status), actions, and the `fragment`/`png` ops from
  clients; these get a status error.

  ## Access

  Subscribing and calling the services are open to any client the
  dashboard lets in. Publishing `/cmd_vel` needs the dashboard's access
  token, given as `ws://HOST:PORT/?token=TOKEN` or with the `auth` op
  (its `mac` field is the token; the other rosauth fields are ignored);
  without it a publish gets a status error and does nothing. Five wrong
  tokens close the connection. Browsers (requests with an `Origin`
  header) must come from an allowed origin (the dashboard's own or its
  `origins` option); clients without one (Node, Foxglove desktop, Python)
  are let in.
  """

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Rosbridge.Topics
  alias ThinkingCap.Tuples
  require Tuples

  @doc """
  The topics served right now, `{name, type}` sorted by name (what
  `/rosapi/topics` answers); `world?` says whether `/map` is served.
  """
  @spec topics(boolean()) :: [{String.t(), String.t()}]
  def topics(world? \\ true) do
    robots =
      for Tuples.robot(id, caps) when is_atom(id) and is_map(caps) <-
            Blackboard.rd_all(Tuples.robot()),
          into: %{},
          do: {Atom.to_string(id), %{id: id, caps: caps}}

    Topics.list(robots, world?)
  end
end
