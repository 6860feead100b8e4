defmodule ThinkingCap.Bench.Dashboard do
  @moduledoc """
  `mix tc.bench dashboard [--seconds S] [--presses N] [--robots R] [--browsers B] [--profile]`:
  the web dashboard in real browsers (Debian's chromium through npm
  playwright-core, `apps/tc_dashboard/test/support/js/driver.mjs`), on
  loopback, with R simulated robots (default 10) in the office world, each
  a `ThinkingCap.Sim.Robot` base at 100 Hz; all but the first spin on the
  spot under "autonomy" so their poses and scans keep changing.

    * **Teleoperation latency**: one page drives the first robot with the
      arrow keys, N presses (default 100), alternating left and right turns
      on the spot, 50–150 ms apart. The page stamps each `teleop` message
      with `sent_at` (epoch ms) when its key handler runs; the robot's base
      echoes it in `{:control, robot, %{mode: :teleop, teleop_sent_at:}}`
      once it has applied the command to the (simulated) wheels; a process
      subscribed to that tuple takes `System.os_time` when it arrives.
      Latency = arrival − sent_at: the page's WebSocket send, the server's
      session, the blackboard, the base's next 10 ms cycle and the timing
      worker's release, and the blackboard back. Measured with one page,
      then again (N/3 presses) with all B pages open.
    * **Frames per second**: B pages (default 10), each its own browser
      context in one chromium, each watching all R robots; the telemetry
      frames each page received over S seconds (default 10), per page, as
      the page counts them (`window.tc.frames`). The server sends at most 25,
      and holds back while a page has 5 frames unacknowledged, so these are
      frames the pages kept up with; the age of each page's latest frame
      shows how far behind the robots the pages are. `--profile` prints
      where one page's time goes (the renderer's trace events and the
      JavaScript functions, through the Chrome DevTools Protocol).
    * **CPU**: the BEAM's own CPU time (utime + stime of the VM, from
      /proc) over S seconds in three states: the robots without the
      dashboard (baseline), with the dashboard and no browser, and with
      the B browsers connected. The dashboard's share is the VM's CPU above
      the baseline with B browsers, as a percentage of the whole machine
      (all cores); the share of one core is printed too, and so is
      chromium's own CPU for context (the browsers run on the same machine
      and compete with the VM).

  Summary: `dashboard: teleop_p50_ms=… teleop_p99_ms=… fps=… cpu_pct=…`
  (fps: the slowest page's). Targets: teleop p99 ≤ 30 ms on loopback,
  fps ≥ 20, cpu_pct ≤ 15.
  """

  alias ThinkingCap.{Blackboard, Dashboard, Runtime}

  @root Path.expand("..", __DIR__)
  @examples Path.join(@root, "priv/examples")
  @wdf Path.join(@examples, "office.wdf")

  Code.require_file(Path.join(@root, "apps/tc_dashboard/test/support/browser.ex"))
  alias ThinkingCap.Dashboard.Test.Browser
  alias ThinkingCap.Bench.ProcStat
  alias ThinkingCap.Tuples
  require Tuples

  def run(args) do
    {opts, _, _} =
      OptionParser.parse(args,
        strict: [
          seconds: :float,
          presses: :integer,
          robots: :integer,
          browsers: :integer,
          profile: :boolean
        ]
      )

    seconds = opts[:seconds] || 10.0
    presses = opts[:presses] || 100
    n_robots = opts[:robots] || 10
    n_browsers = opts[:browsers] || 10

    case Browser.available() do
      :ok -> :ok
      {:error, reason} -> Mix.raise("dashboard bench: no browser: #{reason}")
    end

    :ok = Browser.ensure_assets!()
    cores = System.schedulers_online()
    ticks = ProcStat.clock_ticks()

    IO.puts(
      "dashboard: #{n_robots} simulated robots (office world, 100 Hz bases), " <>
        "#{n_browsers} pages in one headless chromium, #{cores} cores, loopback"
    )

    dir = Path.join(System.tmp_dir!(), "tc_dashboard_bench_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)
    robots = for i <- 0..(n_robots - 1), do: :"b#{i}"
    Enum.each(Enum.with_index(robots), fn {r, i} -> start_robot(dir, r, i) end)
    [first | others] = robots
    spinner = spawn_link(fn -> spin(others) end)
    Process.sleep(1_000)

    # the VM without the dashboard
    base = cpu_window(seconds, ticks)
    IO.puts("  cpu, robots only:              #{pct(base, 1)} of one core")

    token = Base.url_encode64(:crypto.strong_rand_bytes(12), padding: false)
    {:ok, info} = Dashboard.start(port: 0, rosbridge_port: nil, token: token)
    Process.sleep(500)
    idle = cpu_window(seconds, ticks)
    IO.puts("  cpu, dashboard, no browser:    #{pct(idle, 1)} of one core")

    {:ok, browser} = Browser.start_link()
    collector = spawn_link(fn -> collect(first) end)

    url = fn page_robot -> "#{info.url}&robot=#{page_robot}" end
    {:ok, _} = Browser.open(browser, url.(first), page: "p0")

    {:ok, _} =
      Browser.wait(browser, "tc.connected && tc.canControl && tc.drawn['#{first}']",
        page: "p0",
        timeout: 15_000
      )

    Process.sleep(500)

    alone = latencies(browser, collector, first, presses, "p0")
    report("teleop latency, 1 page", alone)

    # the other pages, each watching every robot (and one selected)
    for i <- 1..(n_browsers - 1)//1 do
      page = "p#{i}"
      r = Enum.at(robots, rem(i, n_robots))
      {:ok, _} = Browser.open(browser, url.(r), page: page)

      {:ok, _} =
        Browser.wait(browser, "tc.connected && tc.frames > 0", page: page, timeout: 15_000)
    end

    Process.sleep(2_000)
    pages = for i <- 0..(n_browsers - 1), do: "p#{i}"
    before = Enum.map(pages, &frames(browser, &1))
    chromium_before = chromium_ticks()
    loaded = cpu_window(seconds, ticks)
    chromium_cpu = (chromium_ticks() - chromium_before) / ticks / loaded.wall
    after_ = Enum.map(pages, &frames(browser, &1))

    # how far behind the server each page's view is (same clock: loopback)
    ages =
      for page <- pages do
        {:ok, age} = Browser.eval(browser, "Date.now() - tc.lastTelemetry.t", page: page)
        age
      end

    fps = for {{f0, t0}, {f1, t1}} <- Enum.zip(before, after_), do: (f1 - f0) / ((t1 - t0) / 1000)

    {:ok, frame_bytes} =
      Browser.eval(browser, "JSON.stringify(tc.lastTelemetry).length", page: "p1")

    if opts[:profile], do: profile_page(browser, "p1")

    IO.puts("  cpu, dashboard, #{n_browsers} browsers:  #{pct(loaded, 1)} of one core")

    IO.puts(
      "  fps per page: min #{fmt(Enum.min(fps))}, mean #{fmt(mean(fps))}, max #{fmt(Enum.max(fps))} " <>
        "(#{Enum.map_join(fps, " ", &fmt(&1, 1))})"
    )

    IO.puts(
      "  age of each page's latest frame at the end: max #{fmt(Enum.max(ages), 0)} ms, " <>
        "mean #{fmt(mean(ages), 0)} ms; a telemetry frame is #{frame_bytes} bytes of JSON"
    )

    IO.puts("  chromium (#{n_browsers} pages): #{fmt(chromium_cpu * 100, 0)}% of one core")

    under_load = latencies(browser, collector, first, max(div(presses, 3), 10), "p0")
    report("teleop latency, #{n_browsers} pages", under_load)

    {:ok, _} = Browser.screenshot(browser, "bench_dashboard", page: "p0")
    Browser.stop(browser)
    Process.unlink(spinner)
    Process.exit(spinner, :kill)
    Dashboard.stop()
    for r <- robots, do: Runtime.stop(:"base_#{r}")
    File.rm_rf(dir)

    share_core = (loaded.cpu - base.cpu) / loaded.wall
    share_idle_core = (idle.cpu - base.cpu) / idle.wall
    cpu_pct = share_core / cores * 100

    IO.puts(
      "  dashboard's CPU (VM above the baseline): #{fmt(share_idle_core * 100, 1)}% of one core without browsers, " <>
        "#{fmt(share_core * 100, 1)}% of one core with #{n_browsers} = #{fmt(cpu_pct, 1)}% of the machine (#{cores} cores)"
    )

    stats = summary(alone)

    IO.puts(
      "dashboard: teleop_p50_ms=#{fmt(stats.p50)} teleop_p99_ms=#{fmt(stats.p99)} " <>
        "fps=#{fmt(Enum.min(fps), 1)} cpu_pct=#{fmt(cpu_pct, 1)}"
    )
  end

  # ---- robots ------------------------------------------------------------------

  defp start_robot(dir, robot, i) do
    path = Path.join(dir, "#{robot}.adf")
    x = 1.5 + 1.8 * i

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{@wdf}",
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                        deadline: 0.005, priority: 90, fallback: :stop,
                        params: [at: {#{x}, 1.5, 0.0}, seed: #{i + 1}]]
      ]
    ]
    """)

    {:ok, _} = Runtime.start(path)
    {:ok, _} = Blackboard.rd(Tuples.sim_pose(robot), 10_000)
  end

  # "autonomy" for the other robots: turning on the spot, refreshed within
  # the base's command timeout
  defp spin(robots) do
    for r <- robots do
      {drive, opts} = Tuples.keyed(Tuples.drive(r, %{command: {:velocity, 0.0, 0.5}}))
      Blackboard.out(drive, opts)
    end

    Process.sleep(150)
    spin(robots)
  end

  # ---- teleoperation latency --------------------------------------------------------

  # arrival time of the robot's {:control, ...} tuples that echo a teleop
  # stamp: the first one after each arm
  defp collect(robot) do
    {:ok, ref} = Blackboard.subscribe(Tuples.control(robot))
    collect_loop(ref, nil)
  end

  defp collect_loop(ref, armed) do
    receive do
      {:blackboard, ^ref, Tuples.control(_, %{mode: :teleop, teleop_sent_at: sent} = c)}
      when is_number(sent) and armed != nil ->
        now = System.os_time(:microsecond) / 1000
        send(armed, {:teleop_applied, now - sent, c.command})
        collect_loop(ref, nil)

      {:blackboard, ^ref, _} ->
        collect_loop(ref, armed)

      {:arm, pid} ->
        collect_loop(ref, pid)
    end
  end

  defp latencies(browser, collector, robot, n, page) do
    for i <- 1..n do
      key = if rem(i, 2) == 0, do: "ArrowLeft", else: "ArrowRight"
      send(collector, {:arm, self()})
      :ok = Browser.keydown(browser, key, page: page)

      latency =
        receive do
          {:teleop_applied, ms, _command} -> ms
        after
          2_000 -> raise "press #{i}: the robot did not report a teleop command within 2 s"
        end

      :ok = Browser.keyup(browser, key, page: page)
      await_released(robot)
      Process.sleep(50 + :rand.uniform(100))
      latency
    end
  end

  defp await_released(robot, tries \\ 200) do
    case Blackboard.rdp(Tuples.control(robot)) do
      {:ok, Tuples.control(_, %{mode: :teleop})} when tries > 0 ->
        Process.sleep(5)
        await_released(robot, tries - 1)

      _ ->
        :ok
    end
  end

  defp report(label, samples) do
    s = summary(samples)

    IO.puts(
      "  #{label}: n=#{length(samples)} p50 #{fmt(s.p50)} ms, p90 #{fmt(s.p90)}, " <>
        "p99 #{fmt(s.p99)}, max #{fmt(s.max)}, min #{fmt(s.min)}"
    )
  end

  defp summary(samples) do
    sorted = Enum.sort(samples)

    %{
      p50: pctl(sorted, 0.5),
      p90: pctl(sorted, 0.9),
      p99: pctl(sorted, 0.99),
      min: List.first(sorted),
      max: List.last(sorted)
    }
  end

  # nearest-rank percentile
  defp pctl(sorted, p) do
    k = max(1, ceil(p * length(sorted)))
    Enum.at(sorted, k - 1)
  end

  # ---- frames and CPU ---------------------------------------------------------------

  defp frames(browser, page) do
    {:ok, [f, t]} = Browser.eval(browser, "[tc.frames, performance.now()]", page: page)
    {f, t}
  end

  # the VM's CPU seconds (user + system) over a window of wall seconds
  defp cpu_window(seconds, ticks) do
    c0 = vm_ticks()
    t0 = System.monotonic_time(:microsecond)
    Process.sleep(round(seconds * 1000))
    c1 = vm_ticks()
    wall = (System.monotonic_time(:microsecond) - t0) / 1.0e6
    %{cpu: (c1 - c0) / ticks, wall: wall}
  end

  defp vm_ticks, do: proc_ticks("/proc/self/stat")

  defp proc_ticks(stat) do
    case File.read(stat) do
      {:ok, text} ->
        # fields after the command name (which may hold spaces) in parentheses
        [_, rest] = String.split(text, ") ", parts: 2)
        fields = String.split(rest)
        String.to_integer(Enum.at(fields, 11)) + String.to_integer(Enum.at(fields, 12))

      {:error, _} ->
        0
    end
  end

  # every chromium process (the browser and its renderers)
  defp chromium_ticks do
    for dir <- Path.wildcard("/proc/[0-9]*"),
        String.starts_with?(comm(dir), ["chrom", "headless"]),
        reduce: 0 do
      acc -> acc + proc_ticks(Path.join(dir, "stat"))
    end
  end

  defp comm(dir) do
    case File.read(Path.join(dir, "comm")) do
      {:ok, c} -> c
      _ -> ""
    end
  end

  defp pct(%{cpu: cpu, wall: wall}, _), do: "#{fmt(cpu / wall * 100, 1)}%"

  defp mean([]), do: 0.0
  defp mean(xs), do: Enum.sum(xs) / length(xs)

  defp profile_page(browser, page) do
    {:ok, trace} =
      Browser.command(browser, %{cmd: "trace", page: page, ms: 3000, top: 15}, 20_000)

    {:ok, js} = Browser.command(browser, %{cmd: "profile", page: page, ms: 3000, top: 15}, 20_000)
    IO.puts("  #{page}, trace events over 3 s (ms, every renderer thread):")
    for [name, ms] <- trace, do: IO.puts("    #{String.pad_trailing(name, 60)} #{ms}")
    IO.puts("  #{page}, JavaScript self time over 3 s (ms of #{js["total_ms"]} sampled):")
    for [name, ms] <- js["by"], do: IO.puts("    #{String.pad_trailing(name, 60)} #{ms}")
  end

  defp fmt(x, digits \\ 2)
  defp fmt(nil, _), do: "-"
  defp fmt(x, digits) when is_integer(x), do: fmt(x * 1.0, digits)
  defp fmt(x, 0), do: x |> round() |> Integer.to_string()
  defp fmt(x, digits), do: :erlang.float_to_binary(x, decimals: digits)
end
