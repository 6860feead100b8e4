defmodule ThinkingCap.Dashboard.BlackBoxBrowserTest do
  # The Black box panel in a real browser (chromium, as browser_test.exs):
  # a robot's black box fed a drive down the hall, the timeline opened and
  # its slider dragged, the map drawing the robot, its map and its plan
  # where they were at each instant, and back to live; a dump asked for
  # from the panel, listed and downloaded through its link.
  use ExUnit.Case, async: false

  alias ThinkingCap.{BlackBox, Blackboard, Dashboard}
  alias ThinkingCap.Dashboard.Test.Browser
  import Browser, only: [open!: 2, eval!: 2, page_errors: 1]
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Tuples
  require Tuples

  @moduletag :browser
  @moduletag :tmp_dir

  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @wdf Path.join(@examples, "office.wdf")
  @token "test-token-0123456789"

  setup_all do
    :ok = Browser.ensure_assets!()
    {:ok, browser} = Browser.start_link()
    on_exit(fn -> Browser.stop(browser) end)
    %{browser: browser}
  end

  setup %{tmp_dir: dir} do
    robot = :"bbweb#{System.unique_integer([:positive])}"

    caps = %{
      footprint: %{radius: 0.2},
      sensors: [%{name: :laser, type: :laser, pose: {0.0, 0.0, 0.0}}]
    }

    Blackboard.out(Tuples.robot(robot, caps), key: {:robot, robot})
    {:ok, _} = BlackBox.keep(robot, dir: dir, after: 0.2)
    {:ok, info} = Dashboard.start(port: 0, rosbridge_port: nil, token: @token, world: @wdf)

    on_exit(fn ->
      Dashboard.stop()
      BlackBox.forget(robot)
      drain({:_, robot, :_})
    end)

    %{robot: robot, name: Atom.to_string(robot), info: info}
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  # the learned map: free, with a 1 m box sensed at x 8..9, y 0.5..1.5
  defp box_map do
    {w, h} = {200, 60}

    data =
      for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>> do
        {x, y} = {(c + 0.5) * 0.1, (r + 0.5) * 0.1}
        if x >= 8 and x <= 9 and y >= 0.5 and y <= 1.5, do: <<100>>, else: <<0>>
      end

    %OccupancyGrid{width: w, height: h, data: data, resolution: 0.1, version: 3}
  end

  # a drive down the hall, 0.6 m a step from x 4 to 10, a scan at each
  # step; the plan and the learned map come half-way
  defp drive(robot, bump_at \\ nil) do
    for i <- 0..10 do
      x = 4.0 + 0.6 * i

      Blackboard.out(Tuples.pose(robot, %{pose: {x, 1.8, 0.0}, stamp: i * 1.0}),
        key: {:pose, robot}
      )

      Blackboard.out(
        Tuples.reading(:laser, robot, %{
          ranges: List.duplicate(1.0, 9),
          angle_min: -0.4,
          angle_max: 0.4,
          angle_increment: 0.1,
          range_max: 5.0,
          stamp: i * 1.0
        })
      )

      # a bumper pressed: an incident, the black box dumps
      if i == bump_at do
        Blackboard.out(Tuples.reading(:bumper, robot, %{pressed: true, stamp: i * 1.0}))
      end

      if i == 5 do
        Blackboard.out(Tuples.map(robot, box_map()), key: {:map, robot})

        Blackboard.out(
          Tuples.plan(robot, %{state: :moving, goal: {12.0, 1.8}, path: [{12.0, 1.8}]}),
          key: {:plan, robot}
        )
      end

      Process.sleep(60)
    end
  end

  test "the timeline's slider shows the map, scan, plan and pose of each instant", ctx do
    b = ctx.browser
    drive(ctx.robot)
    name = js(ctx.name)
    open_timeline!(b, ctx)
    wait!(b, "tc.replaying")

    timeline = eval!(b, "tc.timeline")
    assert timeline["streams"]["pose/#{ctx.name}"] == 11
    assert timeline["streams"]["laser/#{ctx.name}"] == 11
    assert timeline["at"] == timeline["to"]

    # the end of the snapshot: the last pose, the box of the map, the plan
    assert_drawn_at(b, ctx.name, 10.0, 1.8)
    assert orange?(b, 8.5, 1.0), "the learned map's box is drawn"
    # the scan's beam at 0.4 rad hits 1 m away; the plan's goal flag
    assert laser_hit?(b, 10.0 + :math.cos(0.4), 1.8 + :math.sin(0.4))
    assert flag?(b, ctx.name, 12.0, 1.8)
    assert eval!(b, "document.getElementById('replay-badge').hidden") == false
    Browser.screenshot(b, "black_box_timeline_end")

    # live, the robot moves on: the timeline's snapshot does not
    Blackboard.out(Tuples.pose(ctx.robot, %{pose: {11.5, 1.8, 0.0}, stamp: 20.0}),
      key: {:pose, ctx.robot}
    )

    wait!(b, "tc.item('pose/' + #{name}).pose[0] === 11.5")
    assert_drawn_at(b, ctx.name, 10.0, 1.8)

    # dragged to its start: the first pose, no map or plan yet
    frames = timeline["frames"]
    drag_slider(b, 0.0)
    wait!(b, "tc.timeline.frames > #{frames} && tc.timeline.at === tc.timeline.from")
    wait!(b, "!tc.timeline.keys.includes('map/' + #{name})")
    assert_drawn_at(b, ctx.name, 4.0, 1.8)
    refute orange?(b, 8.5, 1.0), "no learned map yet"
    refute flag?(b, ctx.name, 12.0, 1.8)
    # the first scan came after the first pose
    refute laser_hit?(b, 4.0 + :math.cos(0.4), 1.8 + :math.sin(0.4))
    assert "plan/#{ctx.name}" not in eval!(b, "tc.timeline.keys")
    Browser.screenshot(b, "black_box_timeline_start")

    # and to the middle of the drive (the snapshot goes on to when it was
    # taken): the pose received last before the instant under the thumb
    {from, to} = {timeline["from"], timeline["to"]}
    middle = pose_time(ctx.robot, 5)
    drag_slider(b, (middle - from) / (to - from), 0.0)
    # the frame of where the thumb stopped (the page asks for the latest
    # position once the frame it waits for has come)
    at =
      wait!(
        b,
        "(s => tc.timeline.at === tc.timeline.from + Number(s.value) && tc.timeline.at)" <>
          "(document.querySelector('.timeline-slider'))"
      )

    assert at > timeline["from"] + 100 and at < timeline["to"] - 100
    {x, _, _} = pose_at(ctx.robot, at)
    assert_drawn_at(b, ctx.name, x, 1.8)
    assert x > 4.0 and x < 10.0

    # back to live: the robot where it is now
    :ok = Browser.click(b, "#tab-blackbox button.timeline-live")
    wait!(b, "!tc.replaying && !tc.timeline.open")
    assert_drawn_at(b, ctx.name, 11.5, 1.8)
    assert eval!(b, "document.getElementById('replay-badge').hidden") == true
    assert page_errors(b) == []
  end

  test "an incident is marked under the slider; a click on it shows its instant", ctx do
    b = ctx.browser
    drive(ctx.robot, 3)
    open_timeline!(b, ctx)

    timeline = eval!(b, "tc.timeline")
    assert [%{"reason" => "bumper", "at" => at}] = timeline["incidents"]
    assert at > timeline["from"] and at < timeline["to"]
    mark = ~s(#tab-blackbox .timeline-mark[data-reason="bumper"])
    assert eval!(b, "document.querySelectorAll('#tab-blackbox .timeline-mark').length") == 1
    assert eval!(b, "document.querySelector(#{js(mark)}).title") =~ "bumper"

    # the mark sits under the slider where the incident is in the span
    [left, width] =
      eval!(
        b,
        "(m => [m.offsetLeft + m.offsetWidth / 2, m.parentElement.clientWidth])" <>
          "(document.querySelector(#{js(mark)}))"
      )

    share = (at - timeline["from"]) / (timeline["to"] - timeline["from"])
    assert abs(left / width - share) < 0.03

    # a click shows the instant of the bump: the robot where it was then
    :ok = Browser.click(b, mark)
    wait!(b, "tc.timeline.at === #{at}")
    {x, _, _} = pose_at(ctx.robot, at)
    assert_drawn_at(b, ctx.name, x, 1.8)
    # the bump came with the fourth pose (x = 5.8)
    assert_in_delta x, 5.8, 0.01
    assert page_errors(b) == []
  end

  test "a dump asked for from the panel is listed and downloads through its link", ctx do
    b = ctx.browser
    drive(ctx.robot)
    open!(b, "#{ctx.info.url}&robot=#{ctx.name}")
    wait!(b, "tc.connected && tc.canControl && tc.selected === #{js(ctx.name)}")
    :ok = Browser.click(b, ~s(.tabs button[data-tab="blackbox"]))
    wait!(b, "document.querySelector('#tab-blackbox .empty')")

    :ok = Browser.click(b, "#tab-blackbox .panel-head button")
    row = "#tab-blackbox table.dumps-table tbody tr"
    wait!(b, "document.querySelector(#{js(row)})", timeout: 20_000)
    assert [dump] = BlackBox.dumps(ctx.robot)
    assert dump.reason == "dashboard"
    assert eval!(b, "document.querySelector(#{js(row)}).dataset.name") == Path.basename(dump.path)

    # the link carries the token; fetched by the page, it is the file
    {:ok, got} =
      Browser.eval(b, """
      (async () => {
        const a = document.querySelector(#{js(row <> " a.download")});
        const res = await fetch(a.href);
        const body = new Uint8Array(await res.arrayBuffer());
        return { status: res.status, bytes: body.length, head: [...body.slice(0, 8)], href: a.getAttribute('href') };
      })()
      """)

    assert got["status"] == 200
    assert got["bytes"] == File.stat!(dump.path).size
    # MCAP's magic
    assert got["head"] == [0x89, ?M, ?C, ?A, ?P, ?0, ?\r, ?\n]
    assert got["href"] =~ "?token=#{@token}"
    assert page_errors(b) == []
  end

  # drags the slider's thumb from where it is to `to` (0: its start, 1: its end)
  defp drag_slider(b, to, from \\ nil) do
    rect =
      eval!(
        b,
        "(r => [r.left, r.top, r.width, r.height])(document.querySelector('.timeline-slider').getBoundingClientRect())"
      )

    [left, top, width, height] = rect

    value =
      from ||
        eval!(
          b,
          "(s => Number(s.value) / Number(s.max))(document.querySelector('.timeline-slider'))"
        )

    # the thumb's centre travels the track less its own width (about 16 px)
    xof = fn f -> left + 8 + f * (width - 16) end
    y = top + height / 2
    from_x = xof.(value)
    to_x = if to >= 1.0, do: left + width + 20, else: if(to <= 0.0, do: left - 20, else: xof.(to))

    {:ok, _} = Browser.command(b, %{cmd: "mousedown", x: from_x, y: y})
    {:ok, _} = Browser.command(b, %{cmd: "mousemove", x: to_x, y: y, steps: 12})
    {:ok, _} = Browser.command(b, %{cmd: "mouseup"})
  end

  # when the black box received the `i`th pose (ms since the epoch)
  # the page on the robot, its Black box tab, the timeline opened and its
  # first frame in
  defp open_timeline!(b, ctx) do
    name = js(ctx.name)
    open!(b, "#{ctx.info.url}&robot=#{ctx.name}")
    wait!(b, "tc.connected && tc.selected === #{name} && tc.drawn[#{name}]")
    :ok = Browser.click(b, ~s(.tabs button[data-tab="blackbox"]))
    :ok = Browser.click(b, "#tab-blackbox button.timeline-open")
    wait!(b, "tc.timeline.open && tc.timeline.frames > 0")
  end

  defp pose_time(robot, i) do
    {:ok, snapshot} = BlackBox.snapshot(robot, tags: [:pose])
    {t, _} = Enum.at(snapshot.entries, i)
    div(t, 1_000_000)
  end

  # the pose the black box had received last at `at_ms`
  defp pose_at(robot, at_ms) do
    {:ok, snapshot} = BlackBox.snapshot(robot, tags: [:pose])

    snapshot.entries
    |> Enum.filter(fn {t, _} -> t <= at_ms * 1_000_000 end)
    |> List.last()
    |> then(fn {_t, Tuples.pose(_, %{pose: pose})} -> pose end)
  end

  defp assert_drawn_at(b, name, x, y) do
    [ex, ey] = eval!(b, "tc.worldToScreen(#{x}, #{y})")

    wait!(
      b,
      "(d => d && Math.abs(d[0] - #{ex}) < 2 && Math.abs(d[1] - #{ey}) < 2)(tc.drawn[#{js(name)}])"
    )
  end

  # whether the map's pixel at a world point is the learned map's orange
  defp orange?(b, x, y) do
    [r, _g, bl] = pixel(b, eval!(b, "tc.worldToScreen(#{x}, #{y})"))
    r > 150 and r > bl + 60
  end

  # whether a laser hit (#ff5252, 2 px) is drawn at a world point: in
  # the 5 x 5 pixels around it (a hit's square falls across pixels)
  defp laser_hit?(b, x, y) do
    [sx, sy] = eval!(b, "tc.worldToScreen(#{x}, #{y})")

    Enum.any?(for(dx <- -2..2, dy <- -2..2, do: {dx, dy}), fn {dx, dy} ->
      [r, g, bl] = pixel(b, [sx + dx, sy + dy])
      r > 200 and g < 130 and bl < 130
    end)
  end

  # whether the goal's flag is drawn at a world point, in the robot's colour
  defp flag?(b, name, x, y) do
    [sx, sy] = eval!(b, "tc.worldToScreen(#{x}, #{y})")
    "#" <> hex = eval!(b, "tc.robotColor(#{js(name)})")
    colour = for <<c::binary-size(2) <- hex>>, do: String.to_integer(c, 16)
    # inside the flag's triangle, right of its pole
    got = pixel(b, [sx + 3, sy - 14])
    Enum.all?(Enum.zip(colour, got), fn {want, have} -> abs(want - have) < 30 end)
  end

  defp pixel(b, [sx, sy]) do
    eval!(b, """
    (() => {
      const c = document.getElementById('map');
      const dpr = window.devicePixelRatio || 1;
      return [...c.getContext('2d').getImageData(Math.round(#{sx} * dpr), Math.round(#{sy} * dpr), 1, 1).data].slice(0, 3);
    })()
    """)
  end

  # generous: the machine may be busy; these are not timing measurements
  defp wait!(b, expr, opts \\ []),
    do: Browser.wait!(b, expr, Keyword.put_new(opts, :timeout, 15_000))

  defp js(value), do: :jiffy.encode(value)
end
