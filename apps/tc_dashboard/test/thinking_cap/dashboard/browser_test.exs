defmodule ThinkingCap.Dashboard.BrowserTest do
  # The dashboard in a real browser: Debian's chromium driven by npm
  # playwright-core (test/support/js/driver.mjs). Each test starts an ADF
  # with a simulated robot and the dashboard, opens the page, drives it
  # like a user (keys, clicks), and checks what the robot did on the
  # blackboard. Screenshots go to apps/tc_dashboard/test/artifacts/.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Dashboard, Runtime, Sim}
  alias ThinkingCap.Dashboard.Test.Browser
  import Browser, only: [open!: 2, eval!: 2, wait!: 2, wait!: 3, page_errors: 1]

  @moduletag :browser
  @moduletag :tmp_dir

  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @wdf Path.join(@examples, "office.wdf")

  # generous bounds on what must happen "at once": these are not timing
  # measurements (the benchmark measures latency), only "it did happen"
  @soon 1_000

  setup_all do
    :ok = Browser.ensure_assets!()
    {:ok, browser} = Browser.start_link()
    on_exit(fn -> Browser.stop(browser) end)
    %{browser: browser}
  end

  setup %{tmp_dir: dir} = ctx do
    robot = :"web#{System.unique_integer([:positive])}"

    # the office (each test's robot on its own stretch of the hall, heading
    # east), or a small occupancy map made for the test
    {wdf, at} =
      if ctx[:grid],
        do: {grid_world(dir), {4.0, 1.0, 0.0}},
        else: {@wdf, {4.0 + rem(System.unique_integer([:positive]), 8) * 1.5, 1.8, 0.0}}

    path = Path.join(dir, "browser.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{wdf}",
      dashboard: [enabled: true, port: 0, rosbridge_port: 0, public_view: #{ctx[:public_view] == true}],
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                         deadline: 0.005, fallback: :stop, params: [at: #{inspect(at)}, seed: 5]]
      ]
    ]
    """)

    {:ok, _} = Runtime.start(path)

    on_exit(fn ->
      Runtime.stop(:"base_#{robot}")
      Dashboard.stop()
      with {:ok, sim} <- Sim.Worlds.lookup(wdf), do: Sim.remove_robot(sim, robot)
    end)

    {:ok, info} = Dashboard.await(10_000)
    {:ok, _} = Blackboard.rd({:sim_pose, robot, :_}, 5_000)
    %{robot: robot, name: Atom.to_string(robot), info: info}
  end

  test "the page loads, connects with control, and the map shows the robot where it is", ctx do
    b = ctx.browser
    open!(b, url(ctx))

    # the robot is drawn on the map, at its simulated pose
    [sx, sy, radius] = wait!(b, "tc.drawn[#{js(ctx.name)}]")
    {x, y, th} = pose(ctx.robot)
    [ex, ey] = eval!(b, "tc.worldToScreen(#{x}, #{y})")
    assert_in_delta sx, ex, 3
    assert_in_delta sy, ey, 3

    # and painted there: the map's pixel beside the centre (off the heading
    # line) has the robot's colour (drawn at 90 % opacity), not the floor's
    "#" <> hex = eval!(b, "tc.robotColor(#{js(ctx.name)})")
    colour = for <<c::binary-size(2) <- hex>>, do: String.to_integer(c, 16)

    pixel =
      eval!(b, pixel_js(sx - radius * 0.5 * :math.sin(th), sy - radius * 0.5 * :math.cos(th)))

    for {want, got} <- Enum.zip(colour, Enum.take(pixel, 3)),
        do:
          assert_in_delta(
            got,
            want,
            30,
            "the robot's pixel is #{inspect(pixel)}, its colour #{hex}"
          )

    # the panels and the status bar follow the telemetry
    assert eval!(b, "tc.canControl") == true
    assert eval!(b, "tc.world && tc.world.name") == "office"
    wait!(b, "tc.frames > 3 && tc.fps > 0")
    wait!(b, "document.querySelector('#control-badge').textContent === 'IDLE'")
    assert eval!(b, "document.querySelector('#banner').hidden") == true
    assert eval!(b, "tc.item('robot/' + #{js(ctx.name)}).limits.max_speed") == 0.4

    Browser.screenshot(b, "page_loaded")
    assert page_errors(b) == []
  end

  test "the learned map and the particles are drawn where the robot learned them", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}]")

    # a learned map of the hall: free, with a 1 m box sensed at x 8..9, y 0.5..1.5
    alias ThinkingCap.Navigation.OccupancyGrid
    {w, h} = {200, 60}

    data =
      for r <- 0..(h - 1), c <- 0..(w - 1), into: <<>> do
        {x, y} = {(c + 0.5) * 0.1, (r + 0.5) * 0.1}
        if x >= 8 and x <= 9 and y >= 0.5 and y <= 1.5, do: <<100>>, else: <<0>>
      end

    map = %OccupancyGrid{width: w, height: h, data: data, resolution: 0.1, version: 7}
    :ok = Blackboard.out({:map, ctx.robot, map}, key: {:map, ctx.robot})
    # other tests read /map: this map must not outlive the test
    on_exit(fn ->
      Blackboard.takep({:map, ctx.robot, :_})
      Blackboard.takep({:particles, ctx.robot, :_})
    end)

    cloud = %{poses: for(i <- 1..50, do: {2.0 + i * 0.01, 2.5, 0.0}), stamp: 1.0}
    :ok = Blackboard.out({:particles, ctx.robot, cloud}, key: {:particles, ctx.robot})

    wait!(
      b,
      "tc.item('map/' + #{js(ctx.name)}) && tc.item('map/' + #{js(ctx.name)}).version === 7"
    )

    wait!(b, "tc.item('particles/' + #{js(ctx.name)})")
    :ok = Browser.eval(b, "tc.redraw && tc.redraw()") |> then(fn _ -> :ok end)
    Process.sleep(300)

    # the box's middle is orange (sensed obstacle), the hall's floor beside it is not
    [bx, by] = eval!(b, "tc.worldToScreen(8.5, 1.0)")
    [r, g, bl | _] = eval!(b, pixel_js(bx, by))
    assert r > 150 and r > bl + 60, "the box is drawn #{inspect([r, g, bl])}"
    [fx, fy] = eval!(b, "tc.worldToScreen(11.5, 2.5)")
    [fr, _fg, fb | _] = eval!(b, pixel_js(fx, fy))
    assert fr < 120 and fb >= fr, "the floor is drawn #{inspect([fr, fb])}"

    Browser.screenshot(b, "learned_map")
    assert page_errors(b) == []
  end

  test "holding an arrow key drives the robot; letting go stops it", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")
    {x0, y0, _} = pose(ctx.robot)

    :ok = Browser.keydown(b, "ArrowUp")

    await(fn ->
      match?(%{mode: :teleop, command: {:velocity, v, _}} when v > 0, control(ctx.robot))
    end)

    # held for a second, three times the deadman time: the page's refreshes
    # keep teleoperation on all along, and the robot moves forward. A page
    # starved of the CPU for the deadman time does let go: then a refresh
    # must have come that late.
    {:ok, ref} = Blackboard.subscribe({:control, ctx.robot, :_})
    {:ok, tref} = Blackboard.subscribe({:teleop, ctx.robot, :_})
    received = receive_for(1_000)
    changes = for {_, {:blackboard, ^ref, {:control, _, c}}} <- received, do: c.mode
    refreshed = for {at, {:blackboard, ^tref, _}} <- received, do: at
    # (unsubscribing drops what is left in the mailbox)
    :ok = Blackboard.unsubscribe(ref)
    :ok = Blackboard.unsubscribe(tref)
    gap = refreshed |> Enum.chunk_every(2, 1, :discard) |> Enum.map(fn [a, b] -> b - a end)
    late = Enum.max([0 | gap])

    assert Enum.all?(changes, &(&1 == :teleop)) or late >= 250,
           "control went #{inspect(changes)} while held, refreshed at most #{late} ms apart"

    assert %{mode: :teleop, teleop_sent_at: sent_at} = control(ctx.robot)
    assert is_float(sent_at) or is_integer(sent_at)
    assert wait!(b, "tc.control === 'teleop' && tc.control") == "teleop"
    assert eval!(b, "document.querySelector('#control-badge').textContent") == "TELEOP"
    {x1, y1, _} = pose(ctx.robot)
    assert x1 - x0 > 0.05, "moved #{x1 - x0} m east"
    assert abs(y1 - y0) < 0.05
    # at the speed slider's default, half the RDF's 0.4 m/s
    assert %{command: {:velocity, v, w}} = control(ctx.robot)
    assert_in_delta v, 0.2, 1.0e-6
    assert_in_delta w, 0.0, 1.0e-6
    Browser.screenshot(b, "teleop_held")

    :ok = Browser.keyup(b, "ArrowUp")
    await(fn -> match?(%{command: :stop}, control(ctx.robot)) end)
    refute control(ctx.robot).mode == :teleop
    await(fn -> speed(ctx.robot) < 0.01 end, 2_000)
    wait!(b, "tc.control !== 'teleop'")
    assert eval!(b, "tc.teleop.command") == nil

    # another key: turning on the spot, left
    :ok = Browser.keydown(b, "KeyA")

    await(fn ->
      match?(
        %{mode: :teleop, command: {:velocity, v, w}} when v == 0 and w > 0,
        control(ctx.robot)
      )
    end)

    :ok = Browser.keyup(b, "KeyA")
    await(fn -> match?(%{command: :stop}, control(ctx.robot)) end)
    assert page_errors(b) == []
  end

  test "a page that stalls while a key is held: the deadman rule stops the robot", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")

    :ok = Browser.keydown(b, "ArrowUp")
    await(fn -> match?(%{mode: :teleop}, control(ctx.robot)) end)

    # the page's main thread freezes for 3 s: no refresh, no release
    stall =
      Task.async(fn ->
        Browser.eval(
          b,
          "(() => { const t = Date.now(); while (Date.now() - t < 3000); return true })()"
        )
      end)

    Process.sleep(50)
    await(fn -> match?(%{mode: :idle, command: :stop}, control(ctx.robot)) end)
    assert Task.yield(stall, 0) == nil, "the robot stopped only after the page came back"
    assert {:ok, true} = Task.await(stall, 10_000)

    :ok = Browser.keyup(b, "ArrowUp")
    await(fn -> match?(%{command: :stop}, control(ctx.robot)) end)
  end

  test "the E-stop stops the robot, holds against the keys, and is released from the page", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")

    :ok = Browser.keydown(b, "ArrowUp")
    await(fn -> match?(%{mode: :teleop, command: {:velocity, _, _}}, control(ctx.robot)) end)
    await(fn -> speed(ctx.robot) > 0.05 end, 2_000)

    :ok = Browser.click(b, "#estop")
    await(fn -> match?(%{mode: :estop, command: :stop}, control(ctx.robot)) end)
    await(fn -> speed(ctx.robot) < 0.01 end, 2_000)
    assert {:ok, {:estop, _, %{engaged: true}}} = Blackboard.rdp({:estop, ctx.robot, :_})
    wait!(b, "tc.control === 'estop'")
    assert eval!(b, "document.querySelector('#control-badge').textContent") == "E-STOP"
    Browser.screenshot(b, "estop")

    # keys while stopped: the robot stays stopped
    :ok = Browser.keyup(b, "ArrowUp")
    :ok = Browser.keydown(b, "ArrowUp")
    Process.sleep(400)
    assert %{mode: :estop, command: :stop} = control(ctx.robot)
    :ok = Browser.keyup(b, "ArrowUp")

    :ok = Browser.click(b, "#estop-release")

    await(fn ->
      match?({:ok, {:estop, _, %{engaged: false}}}, Blackboard.rdp({:estop, ctx.robot, :_}))
    end)

    await(fn -> control(ctx.robot).mode != :estop end)
    wait!(b, "tc.control !== 'estop'")

    # Space is the E-stop too
    :ok = Browser.command(b, %{cmd: "press", key: "Space"}) |> ok()
    await(fn -> match?(%{mode: :estop}, control(ctx.robot)) end)
    assert page_errors(b) == []
  end

  test "the joystick overrides autonomy only while held, and the page shows who is in control",
       ctx do
    b = ctx.browser
    autonomy = start_autonomy(ctx.robot, {:velocity, 0.0, 0.3})
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")
    await(fn -> match?(%{mode: :autonomy}, control(ctx.robot)) end)
    wait!(b, "document.querySelector('#control-badge').textContent === 'AUTONOMY'")

    # drag the joystick's knob straight up: forward
    [cx, cy] = centre(b, "#joystick")
    {:ok, _} = Browser.command(b, %{cmd: "mousedown", x: cx, y: cy})
    {:ok, _} = Browser.command(b, %{cmd: "mousemove", x: cx, y: cy - 40, steps: 4})

    await(fn ->
      match?(
        %{mode: :teleop, command: {:velocity, v, w}} when v > 0.05 and abs(w) < 0.01,
        control(ctx.robot)
      )
    end)

    wait!(b, "document.querySelector('#control-badge').textContent === 'TELEOP'")
    assert eval!(b, "tc.teleop.command.source") == "joystick"
    Browser.screenshot(b, "joystick")

    # let go: autonomy drives again
    {:ok, _} = Browser.command(b, %{cmd: "mouseup"})

    await(fn ->
      match?(%{mode: :autonomy, command: {:velocity, +0.0, 0.3}}, control(ctx.robot))
    end)

    wait!(b, "document.querySelector('#control-badge').textContent === 'AUTONOMY'")
    Task.shutdown(autonomy, :brutal_kill)
  end

  test "a gamepad drives the robot while its stick is pushed; its B button is the E-stop", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")

    # a gamepad, as the Gamepad API would show it, stick pushed forward
    eval!(b, """
    (() => {
      const pad = { index: 0, id: 'Test pad', connected: true, axes: [0, -0.8, 0, 0],
                    buttons: Array.from({ length: 16 }, () => ({ pressed: false, value: 0 })) };
      navigator.getGamepads = () => [pad];
      window.testPad = pad;
      const e = new Event('gamepadconnected');
      e.gamepad = pad;
      window.dispatchEvent(e);
      return true;
    })()
    """)

    await(fn ->
      match?(%{mode: :teleop, command: {:velocity, v, _}} when v > 0.05, control(ctx.robot))
    end)

    assert eval!(b, "tc.teleop.command.source") == "gamepad"

    # the stick back in its dead zone: let go
    eval!(b, "(testPad.axes[1] = 0.05, true)")
    await(fn -> match?(%{mode: :idle, command: :stop}, control(ctx.robot)) end)

    eval!(b, "(testPad.buttons[1].pressed = true, true)")
    await(fn -> match?(%{mode: :estop}, control(ctx.robot)) end)
    assert page_errors(b) == []
  end

  test "the modules panel restarts the robot's module and counts the restart", ctx do
    b = ctx.browser
    base = :"base_#{ctx.name}"
    before = Runtime.whereis({ctx.robot, base})
    open!(b, url(ctx))
    wait!(b, "tc.connected")
    eval!(b, "(document.querySelector('button[data-tab=modules]').click(), true)")
    row = "tr[data-module=#{base}]"

    wait!(
      b,
      "!!document.querySelector('#{row} button') && !document.querySelector('#{row} button').disabled"
    )

    :ok = Browser.click(b, "#{row} button")
    wait!(b, "document.querySelector('#{row} td.num').textContent === '1'", timeout: 10_000)
    after_ = Runtime.whereis({ctx.robot, base})
    assert is_pid(after_) and after_ != before
    assert page_errors(b) == []
  end

  test "the blackboard inspector queries by template and tails a tag", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.connected")
    eval!(b, "(document.querySelector('button[data-tab=blackboard]').click(), true)")

    # a query: the robot's true pose, one tuple
    eval!(b, "(document.querySelector('#bb-template').value = 'sim_pose, #{ctx.name}, _', true)")
    :ok = Browser.click(b, "#bb-query")
    wait!(b, "document.querySelectorAll('#bb-results details').length === 1")
    text = eval!(b, "document.querySelector('#bb-results details summary').textContent")
    assert text =~ "sim_pose" and text =~ ctx.name and text =~ "pose"

    # a template that matches nothing, and one that is not a template
    eval!(
      b,
      "(document.querySelector('#bb-template').value = 'sim_pose, nobody_here_#{ctx.name}, _', true)"
    )

    :ok = Browser.click(b, "#bb-query")
    wait!(b, "document.querySelector('.bb-status').textContent.startsWith('0 tuples')")
    eval!(b, "(document.querySelector('#bb-template').value = '[1, 2', true)")
    :ok = Browser.click(b, "#bb-query")
    wait!(b, "document.querySelector('.bb-status').classList.contains('error')")

    # a tail: the odometry as it comes
    eval!(
      b,
      "(document.querySelector('#bb-template').value = '[\"odom\", \"#{ctx.name}\", \"_\"]', true)"
    )

    :ok = Browser.click(b, "#bb-tail")
    wait!(b, "document.querySelectorAll('#bb-results details').length >= 3")
    Browser.screenshot(b, "blackboard_tail")
    :ok = Browser.click(b, "#bb-tail")

    n =
      wait!(
        b,
        "document.querySelector('.bb-status').textContent.startsWith('Tail stopped') && tc.frames"
      )

    assert is_integer(n)
    assert page_errors(b) == []
  end

  test "a click on the map sends the robot a goal there; a click on a waypoint, to it by name",
       ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.canControl")
    {rx, _, _} = pose(ctx.robot)

    # a point of the hall away from the robot
    gx = if rx > 10, do: 3.0, else: 17.0
    click_world(b, gx, 1.2)

    assert {:ok, {:task, _, %{task: {:go_to, {x, y}}}}} =
             Blackboard.rd({:task, ctx.robot, :_}, @soon)

    assert_in_delta x, gx, 0.05
    assert_in_delta y, 1.2, 0.05

    # desk_b, a waypoint of office.wdf at (16.5, 7.5)
    click_world(b, 16.5, 7.5)

    await(fn ->
      match?(
        {:ok, {:task, _, %{task: {:go_to, :desk_b}}}},
        Blackboard.rdp({:task, ctx.robot, :_})
      )
    end)

    Browser.screenshot(b, "goal")
  end

  @tag grid: true
  test "an occupancy map is drawn the right way up", ctx do
    b = ctx.browser
    open!(b, url(ctx))
    wait!(b, "tc.drawn[#{js(ctx.name)}] && tc.world && tc.world.grid")

    # the robot's own readings off, to see the map alone
    eval!(b, """
    (() => {
      for (const l of document.querySelectorAll('#layers-menu label'))
        if (['Laser', 'Sonar', 'LPS'].includes(l.textContent)) l.querySelector('input').click();
      return true;
    })()
    """)

    Process.sleep(100)
    # the occupied block is in the map's top left (north-west), its mirror
    # image across the map's middle is free floor, outside the map is
    # nothing (points off the origin's axes)
    occupied = world_pixel(b, 0.3, 2.2)
    free = world_pixel(b, 0.3, -0.2)
    assert Enum.all?(Enum.take(occupied, 3), &(&1 > 150)), "occupied: #{inspect(occupied)}"
    assert Enum.all?(Enum.take(free, 3), &(&1 < 80)), "free: #{inspect(free)}"
    refute Enum.take(free, 3) == Enum.take(world_pixel(b, -3.0, 2.0), 3)
    Browser.screenshot(b, "occupancy_map")
  end

  test "a wrong token is refused: the page says so and drives nothing", ctx do
    b = ctx.browser
    {x0, y0, _} = pose(ctx.robot)
    open!(b, "http://127.0.0.1:#{ctx.info.port}/?token=not-the-token-0000&robot=#{ctx.name}")

    reason = wait!(b, "tc.refused", timeout: 5_000)
    assert reason =~ "token"
    assert eval!(b, "tc.connected") == false
    assert eval!(b, "tc.welcomed") == false

    banner =
      wait!(
        b,
        "!document.querySelector('#banner').hidden && document.querySelector('#banner').textContent"
      )

    assert banner =~ "refused"
    Browser.screenshot(b, "wrong_token")

    :ok = Browser.keydown(b, "ArrowUp")
    Process.sleep(500)
    :ok = Browser.keyup(b, "ArrowUp")
    assert Blackboard.rdp({:teleop, ctx.robot, :_}) == :none
    {x1, y1, _} = pose(ctx.robot)
    assert_in_delta x1, x0, 0.01
    assert_in_delta y1, y0, 0.01

    # no token at all: refused as well
    open!(b, "http://127.0.0.1:#{ctx.info.port}/")
    assert wait!(b, "tc.refused", timeout: 5_000) =~ "token"
  end

  @tag public_view: true
  test "with public_view, a viewer without the token watches read-only but may press the E-stop",
       ctx do
    b = ctx.browser
    open!(b, "http://127.0.0.1:#{ctx.info.port}/?robot=#{ctx.name}")
    wait!(b, "tc.connected && tc.welcomed && tc.drawn[#{js(ctx.name)}]")
    assert eval!(b, "tc.canControl") == false

    assert wait!(
             b,
             "!document.querySelector('#banner').hidden && document.querySelector('#banner').textContent"
           ) =~
             "Read-only"

    assert eval!(b, "document.body.classList.contains('read-only')") == true

    :ok = Browser.keydown(b, "ArrowUp")
    Process.sleep(400)
    :ok = Browser.keyup(b, "ArrowUp")
    assert Blackboard.rdp({:teleop, ctx.robot, :_}) == :none
    assert eval!(b, "tc.teleop.sent") == 0
    Browser.screenshot(b, "read_only")

    :ok = Browser.click(b, "#estop")
    await(fn -> match?(%{mode: :estop}, control(ctx.robot)) end)
  end

  # ---- helpers ------------------------------------------------------------------

  defp url(ctx), do: ctx.info.url <> "&robot=#{ctx.name}"

  defp ok({:ok, _}), do: :ok
  defp ok(other), do: other

  defp js(string), do: :jiffy.encode(string)

  # a ROS map_server map, 6 m x 4 m at 10 cm, its origin at (-1, -1): free
  # floor inside a wall, and an occupied 1 m block whose centre is at
  # (0, 2), near the top left of the image (a PGM's first row is the map's
  # top, its north)
  defp grid_world(dir) do
    {w, h} = {60, 40}

    pixels =
      for row <- 0..(h - 1), col <- 0..(w - 1), into: <<>> do
        wall = row == 0 or col == 0 or row == h - 1 or col == w - 1
        block = row in 5..14 and col in 5..14
        if wall or block, do: <<0>>, else: <<254>>
      end

    File.write!(Path.join(dir, "grid.pgm"), ["P5\n#{w} #{h}\n255\n", pixels])

    File.write!(Path.join(dir, "grid.yaml"), """
    image: grid.pgm
    resolution: 0.1
    origin: [-1.0, -1.0, 0.0]
    negate: 0
    occupied_thresh: 0.65
    free_thresh: 0.196
    """)

    path = Path.join(dir, "grid.wdf")
    File.write!(path, ~s([name: "grid_test", map: [yaml: "#{Path.join(dir, "grid.yaml")}"]]))
    path
  end

  defp world_pixel(b, x, y) do
    [sx, sy] = eval!(b, "tc.worldToScreen(#{x}, #{y})")
    eval!(b, pixel_js(sx, sy))
  end

  # a pixel of the map canvas, at CSS pixel coordinates
  defp pixel_js(x, y) do
    """
    (() => {
      const c = document.getElementById('map');
      const dpr = window.devicePixelRatio || 1;
      return [...c.getContext('2d').getImageData(Math.round(#{x} * dpr), Math.round(#{y} * dpr), 1, 1).data];
    })()
    """
  end

  # clicks the map at a world point
  defp click_world(b, x, y) do
    [px, py] =
      eval!(b, """
      (() => {
        const r = document.getElementById('map').getBoundingClientRect();
        const [sx, sy] = tc.worldToScreen(#{x}, #{y});
        return [r.left + sx, r.top + sy];
      })()
      """)

    {:ok, _} = Browser.command(b, %{cmd: "mouse", x: px, y: py})
  end

  # the centre of an element, in page coordinates
  defp centre(b, selector) do
    eval!(b, """
    (() => {
      const r = document.querySelector(#{js(selector)}).getBoundingClientRect();
      return [r.left + r.width / 2, r.top + r.height / 2];
    })()
    """)
  end

  # "autonomy": a controller's command on the blackboard, refreshed within
  # the base's command timeout, until the task is stopped
  defp start_autonomy(robot, command) do
    Task.async(fn ->
      Stream.repeatedly(fn ->
        Blackboard.out({:drive, robot, %{command: command}}, key: {:drive, robot})
        Process.sleep(100)
      end)
      |> Stream.run()
    end)
  end

  defp pose(robot) do
    {:ok, {:sim_pose, ^robot, %{pose: pose}}} = Blackboard.rd({:sim_pose, robot, :_}, 2_000)
    pose
  end

  defp speed(robot) do
    {:ok, {:odom, ^robot, %{twist: {v, _w}}}} = Blackboard.rd({:odom, robot, :_}, 2_000)
    abs(v)
  end

  defp control(robot) do
    case Blackboard.rdp({:control, robot, :_}) do
      {:ok, {:control, ^robot, control}} -> control
      :none -> nil
    end
  end

  # the messages that come within ms, each with the moment it came (ms)
  defp receive_for(ms) do
    deadline = System.monotonic_time(:millisecond) + ms

    Stream.repeatedly(fn ->
      receive do
        message -> {System.monotonic_time(:millisecond), message}
      after
        max(deadline - System.monotonic_time(:millisecond), 0) -> :done
      end
    end)
    |> Enum.take_while(&(&1 != :done))
  end

  defp await(fun, timeout \\ @soon) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      cond do
        fun.() -> true
        System.monotonic_time(:millisecond) > deadline -> flunk("not reached in #{timeout} ms")
        true -> Process.sleep(10) && nil
      end
    end)
    |> Enum.find(& &1)
  end
end
