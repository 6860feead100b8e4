defmodule ThinkingCap.Dashboard.BlackBoxTest do
  # The black box in the dashboard, server side: the dumps listed over the
  # page's socket, downloaded over HTTP behind the token (bad names and
  # strangers refused with their reason), a dump asked for from the page,
  # and the timeline's frames scrubbed from a snapshot.
  use ThinkingCap.Dashboard.Test.Case, async: false

  alias ThinkingCap.{BlackBox, Blackboard}
  alias ThinkingCap.Dashboard.Timeline
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :tmp_dir

  setup %{tmp_dir: dir} do
    robot = :"bbd#{System.unique_integer([:positive])}"
    caps = %{sensors: [%{name: :front, type: :laser}, %{name: :ring, type: :sonar}]}
    Blackboard.out(Tuples.robot(robot, caps), key: {:robot, robot})

    on_exit(fn ->
      BlackBox.forget(robot)
      drain({:_, robot, :_})
    end)

    %{robot: robot, name: Atom.to_string(robot), dir: dir}
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  defp keep(ctx) do
    {:ok, pid} = BlackBox.keep(ctx.robot, dir: ctx.dir, after: 0.1)
    pid
  end

  # a dump written now, with a few poses in it
  defp dump!(ctx, reason) do
    for i <- 1..3, do: Blackboard.out(Tuples.pose(ctx.robot, %{pose: {i * 1.0, 0.0, 0.0}}))
    {:ok, path} = BlackBox.dump(ctx.robot, reason)
    path
  end

  # one HTTP request on a socket of its own; the status, headers and body
  defp http(info, path, opts \\ []) do
    method = Keyword.get(opts, :method, "GET")
    headers = for {k, v} <- Keyword.get(opts, :headers, []), do: "#{k}: #{v}\r\n"
    {:ok, s} = :gen_tcp.connect(~c"127.0.0.1", info.port, [:binary, active: false])

    :ok =
      :gen_tcp.send(s, [
        "#{method} #{path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n",
        headers,
        "\r\n"
      ])

    response = read_all(s, "")
    :gen_tcp.close(s)
    [head, body] = String.split(response, "\r\n\r\n", parts: 2)
    [status_line | header_lines] = String.split(head, "\r\n")
    [_, status | _] = String.split(status_line, " ")

    headers =
      Map.new(header_lines, fn line ->
        [k, v] = String.split(line, ": ", parts: 2)
        {String.downcase(k), v}
      end)

    body = if headers["transfer-encoding"] == "chunked", do: dechunk(body, ""), else: body
    {String.to_integer(status), headers, body}
  end

  defp read_all(s, acc) do
    case :gen_tcp.recv(s, 0, 5_000) do
      {:ok, data} -> read_all(s, acc <> data)
      {:error, :closed} -> acc
    end
  end

  defp dechunk(data, acc) do
    [size, rest] = String.split(data, "\r\n", parts: 2)

    case String.to_integer(size, 16) do
      0 ->
        acc

      n ->
        <<chunk::binary-size(n), "\r\n", rest::binary>> = rest
        dechunk(rest, acc <> chunk)
    end
  end

  defp download_path(ctx, name, token \\ token()),
    do: "/dumps/#{ctx.name}/#{name}?token=#{token}"

  test "the page lists a robot's dumps; each downloads with the token", ctx do
    keep(ctx)
    older = dump!(ctx, "first")
    newer = dump!(ctx, "second")

    {_welcome, client} = connect!(ctx.dashboard)
    {reply, _client} = request(client, %{op: "dumps", robot: ctx.name})
    assert %{"op" => "dumps", "robot" => name, "keeping" => true, "total" => 2} = reply
    assert [a, b] = reply["dumps"]
    assert name == ctx.name
    assert a["name"] == Path.basename(newer) and b["name"] == Path.basename(older)
    assert a["reason"] == "second" and b["reason"] == "first"
    assert a["bytes"] == File.stat!(newer).size
    assert a["url"] == "/dumps/#{ctx.name}/#{Path.basename(newer)}"
    # the file's time, to the millisecond, in the last minute
    assert_in_delta a["time"], System.os_time(:millisecond), 60_000

    {status, headers, body} = http(ctx.dashboard, a["url"] <> "?token=#{token()}")
    assert status == 200
    assert body == File.read!(newer)
    assert headers["content-type"] == "application/octet-stream"

    assert headers["content-disposition"] ==
             ~s(attachment; filename="#{Path.basename(newer)}")
  end

  test "a download without the token, or from a foreign origin, is refused", ctx do
    keep(ctx)
    name = ctx |> dump!("x") |> Path.basename()

    assert {401, _, body} = http(ctx.dashboard, "/dumps/#{ctx.name}/#{name}")
    assert body =~ "downloading a dump needs the access token"
    assert {401, _, _} = http(ctx.dashboard, download_path(ctx, name, "wrong-token-0123456789"))

    assert {403, _, "origin http://evil.example is not allowed\n"} =
             http(ctx.dashboard, download_path(ctx, name),
               headers: [{"Origin", "http://evil.example"}]
             )

    assert {405, _, "a dump is downloaded with GET, not POST\n"} =
             http(ctx.dashboard, download_path(ctx, name), method: "POST")

    # the page's own origin is let through
    origin = "http://127.0.0.1:#{ctx.dashboard.port}"

    assert {200, _, _} =
             http(ctx.dashboard, download_path(ctx, name), headers: [{"Origin", origin}])
  end

  @tag dashboard: [public_view: true]
  test "with public_view a viewer downloads, but may not ask for a dump", ctx do
    keep(ctx)
    name = ctx |> dump!("x") |> Path.basename()
    assert {200, _, _} = http(ctx.dashboard, "/dumps/#{ctx.name}/#{name}")

    {_welcome, client} = connect!(ctx.dashboard, "")
    {reply, _client} = request(client, %{op: "dump", robot: ctx.name})
    assert reply["message"] == "dump needs the access token (this page is read-only)"
  end

  test "paths out of the dumps, unknown dumps and robots are refused with their reason", ctx do
    keep(ctx)
    name = ctx |> dump!("x") |> Path.basename()
    # a file beside the dumps that is not one of them
    File.write!(Path.join(ctx.dir, "#{ctx.robot}_secret.mcap"), "not a dump")

    for bad <- [
          "..%2F..%2F..%2Fetc%2Fpasswd",
          "%2Fetc%2Fpasswd",
          "..%2F#{name}",
          ".%2E%2F#{name}",
          "#{name}%2F..",
          "#{name}%0A"
        ] do
      assert {400, _, body} = http(ctx.dashboard, download_path(ctx, bad)), bad
      assert body =~ "a dump's name is a file name such as #{ctx.robot}_", bad
    end

    # a NUL yaws refuses itself
    assert {400, _, _} = http(ctx.dashboard, download_path(ctx, "%00#{name}"))

    assert {400, _, body} = http(ctx.dashboard, "/dumps/#{ctx.name}/a/#{name}?token=#{token()}")
    assert body =~ "a dump is downloaded from /dumps/ROBOT/NAME"
    assert {400, _, _} = http(ctx.dashboard, "/dumps/#{ctx.name}?token=#{token()}")

    assert {404, _, body} = http(ctx.dashboard, download_path(ctx, "#{ctx.robot}_secret.mcap"))
    assert body == "no dump \"#{ctx.robot}_secret.mcap\" of #{ctx.robot}\n"

    assert {404, _, "no robot \"nobody_here\"\n"} =
             http(ctx.dashboard, "/dumps/nobody_here/#{name}?token=#{token()}")

    # yaws takes the dots out of a path before any appmod sees it: this
    # one is /etc/passwd, not under the docroot
    assert {404, _, body} = http(ctx.dashboard, "/dumps/#{ctx.name}/../../../etc/passwd")
    refute body =~ "root:"
  end

  test "a dump asked for from the page is written and listed", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    # no black box yet: refused, saying why
    {reply, client} = request(client, %{op: "dump", robot: ctx.name})
    assert reply["message"] =~ "#{ctx.robot} has no black box on this node"
    {reply, client} = request(client, %{op: "dumps", robot: ctx.name})
    assert %{"keeping" => false, "dumps" => []} = reply

    keep(ctx)
    {:ok, _} = Blackboard.subscribe(Tuples.black_box_dump(ctx.robot))
    {reply, client} = request(client, %{op: "dump", robot: ctx.name})
    assert reply["op"] == "ok"

    assert_receive {:blackboard, _, Tuples.black_box_dump(_, %{reason: "dashboard"} = dump)},
                   5_000

    {:ok, Tuples.black_box_request(_, request)} =
      Blackboard.rdp(Tuples.black_box_request(ctx.robot))

    assert "page 127.0.0.1:" <> _ = request.by

    {reply, _client} = request(client, %{op: "dumps", robot: ctx.name})
    assert [%{"reason" => "dashboard", "name" => name}] = reply["dumps"]
    assert name == Path.basename(dump.path)
  end

  defp grid(version, fill) do
    %OccupancyGrid{width: 4, height: 2, data: :binary.copy(<<fill>>, 8), version: version}
  end

  # tuples a few ms apart, so that their receipt times differ
  defp out_apart(tuple) do
    Process.sleep(15)
    Blackboard.out(tuple)
  end

  test "the timeline answers each instant's pose, scan, plan and map from its snapshot", ctx do
    # on the blackboard before the black box starts, and never again
    Blackboard.out(Tuples.plan(ctx.robot, %{state: :moving, path: [{1.0, 1.0}]}),
      key: {:plan, ctx.robot}
    )

    pid = keep(ctx)

    for i <- 1..5 do
      out_apart(Tuples.pose(ctx.robot, %{pose: {i * 1.0, 0.0, 0.0}, stamp: i * 1.0}))
      out_apart(Tuples.reading(:front, ctx.robot, %{ranges: [i * 1.0], stamp: i * 1.0}))
      if i == 2, do: out_apart(Tuples.map(ctx.robot, grid(1, 0)))
      if i == 4, do: out_apart(Tuples.map(ctx.robot, grid(2, 100)))
    end

    await(fn -> BlackBox.RingBuffer.info(pid).messages == 12 end)
    {_welcome, client} = connect!(ctx.dashboard)

    {reply, client} = request(client, %{op: "timeline_frame", at: 0})
    assert reply["message"] == "no timeline is open: open one (op timeline) first"

    {summary, client} = request(client, %{op: "timeline", robot: ctx.name})
    assert %{"op" => "timeline", "from" => from, "to" => to, "streams" => streams} = summary
    r = ctx.name

    assert streams == %{
             "pose/#{r}" => 5,
             "front/#{r}" => 5,
             "map/#{r}" => 2,
             "plan/#{r}" => 1,
             "robot/#{r}" => 1
           }

    # what came after the snapshot is not in it
    Blackboard.out(Tuples.pose(ctx.robot, %{pose: {99.0, 0.0, 0.0}}))
    {:ok, snapshot} = BlackBox.snapshot(ctx.robot, tags: [:pose])
    # each pose's receipt, in ms rounded up (the page speaks ms)
    times = for {t, _} <- snapshot.entries, do: div(t + 999_999, 1_000_000)

    frame = fn client, at, have ->
      {reply, client} = request(client, %{op: "timeline_frame", at: at, map: have})
      assert reply["op"] == "timeline_frame" and reply["robot"] == r, inspect(reply)
      {reply, client}
    end

    # the start (earlier is taken to it): the first pose, nothing yet of
    # the streams that came later in the span, the plan from the
    # blackboard (none came in the span: it held all along)
    {f, client} = frame.(client, from - 1_000, :null)
    assert f["at"] == from
    assert f["items"]["pose/#{r}"]["pose"] == [1.0, 0.0, 0.0]
    assert f["items"]["front/#{r}"] == nil and f["items"]["map/#{r}"] == nil
    assert f["items"]["plan/#{r}"]["path"] == [[1.0, 1.0]]
    assert f["map"] == nil

    # at the third pose: the first map, the second scan (the third came
    # after the third pose)
    {f, client} = frame.(client, Enum.at(times, 2), :null)
    assert f["items"]["pose/#{r}"]["pose"] == [3.0, 0.0, 0.0]
    assert f["items"]["front/#{r}"]["ranges"] == [2.0]
    assert %{"version" => 1, "data" => data} = f["items"]["map/#{r}"]
    assert Base.decode64!(data) == :binary.copy(<<0>>, 8)
    first_map = f["map"]
    assert is_integer(first_map)

    # the same map is not sent again to a page that has it
    {f, client} = frame.(client, Enum.at(times, 3), first_map)
    assert f["items"]["pose/#{r}"]["pose"] == [4.0, 0.0, 0.0]
    refute Map.has_key?(f["items"], "map/#{r}")
    assert f["map"] == first_map

    # the last instant: the second map (a new one: sent), not the pose 99
    {f, client} = frame.(client, to + 5_000, first_map)
    assert f["at"] == to
    assert f["items"]["pose/#{r}"]["pose"] == [5.0, 0.0, 0.0]
    assert f["items"]["map/#{r}"]["version"] == 2
    assert f["map"] != first_map

    {reply, client} = request(client, %{op: "timeline_frame", at: "soon"})
    assert reply["message"] == ~s(at must be a number, not "soon")
    {reply, client} = request(client, %{op: "timeline_frame", at: to, map: "x"})
    assert reply["message"] =~ "map is the integer a frame gave, or null"

    # closed by the page, or with its socket
    [{_, timeline, _, _}] = DynamicSupervisor.which_children(ThinkingCap.Dashboard.Timelines)
    ref = Process.monitor(timeline)
    {%{"op" => "ok"}, client} = request(client, %{op: "timeline_close"})
    assert_receive {:DOWN, ^ref, :process, _, _}, 2_000
    {reply, client} = request(client, %{op: "timeline_frame", at: to})
    assert reply["message"] =~ "no timeline is open"

    {%{"op" => "timeline"}, client} = request(client, %{op: "timeline", robot: r})
    [{_, timeline, _, _}] = DynamicSupervisor.which_children(ThinkingCap.Dashboard.Timelines)
    ref = Process.monitor(timeline)
    WSClient.close(client)
    assert_receive {:DOWN, ^ref, :process, _, :normal}, 2_000
  end

  test "timelines are bounded per node; a robot without a black box has none", ctx do
    assert {:error, message} = Timeline.open(ctx.robot, self())
    assert message =~ "#{ctx.robot} has no black box on this node"

    keep(ctx)
    max = Timeline.max_open()

    owners =
      for _ <- 1..max do
        owner = spawn(fn -> Process.sleep(:infinity) end)
        assert {:ok, _pid, %{robot: robot}} = Timeline.open(ctx.robot, owner)
        assert robot == ctx.robot
        owner
      end

    assert {:error, "#{max} timelines are open on this node, the most it keeps: close one first"} ==
             Timeline.open(ctx.robot, self())

    # one owner gone: its timeline closes, and there is room again
    Process.exit(hd(owners), :kill)

    await(fn -> DynamicSupervisor.count_children(ThinkingCap.Dashboard.Timelines).active < max end)

    assert {:ok, pid, _} = Timeline.open(ctx.robot, self())
    Timeline.close(pid)
    for o <- tl(owners), do: Process.exit(o, :kill)
    await(fn -> DynamicSupervisor.count_children(ThinkingCap.Dashboard.Timelines).active == 0 end)
  end

  defp await(fun, tries \\ 200) do
    cond do
      fun.() -> :ok
      tries == 0 -> flunk("not reached")
      true -> Process.sleep(10) && await(fun, tries - 1)
    end
  end
end
