defmodule ThinkingCap.Dashboard.NodeStopTest do
  # A node running the dashboard stops as a release's `stop` stops it
  # (`init:stop/0`): the robots must stop before anything else, the web
  # server included. yaws once ran as an application started after the
  # dashboard's, so the node stopped it first and the robot drove on for
  # the 2 s yaws took to close.
  use ExUnit.Case, async: false
  @moduletag :tmp_dir

  alias ThinkingCap.Dashboard.Test.StopProbe
  alias ThinkingCap.Testing.Cluster

  test "a node told to stop stops its robots before its web server", %{tmp_dir: dir} do
    [node] = Cluster.start(1, apps: [:tc_dashboard])
    on_exit(fn -> Cluster.stop(node) end)

    assert {:ok, _} = Cluster.call(node, ThinkingCap.Dashboard, :start, [[port: 0]])
    path = Path.join(dir, "first")
    Cluster.call(node, StopProbe, :watch, [path])

    Cluster.cast(node, :init, :stop, [])
    Cluster.wait_until(fn -> File.exists?(path) end, 15_000)
    assert File.read!(path) == "robots stopped first"
  end
end
