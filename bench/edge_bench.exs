defmodule ThinkingCap.Bench.Edge do
  @moduledoc """
  `mix tc.bench edge [--quick]`: the network edge under abuse while the
  default robot (`priv/examples/office_sim.adf`: the simulated base at
  100 Hz, perception, MCL, the mapper, the blender, the planner) drives
  its patrol, with the dashboard, rosbridge and the E-stop port on free
  ports of loopback.

  Each scenario runs from OS processes of their own
  (`bench/support/edge_flood.exs`), as a hostile client on the same host
  would:

    * `connections`: 20,000 TCP connections, half to the page, half to
      rosbridge, held 5 s without a byte sent;
    * `wrong_token`: 10,000 page requests with a wrong token;
    * `map`: 1,000 rosbridge subscribes to /map (and unsubscribes);
    * `restarts`: 200 module restart requests, with the token;
    * `malformed`: 1,000 malformed page messages, with the token.

  One second into each, an E-stop is asked on the E-stop port; the time
  to the base applying the stop (its `{:control, robot, %{mode: :estop}}`)
  is estop_ms; the E-stop is then released. A scenario is survived when,
  after it, the page is served with the token within 10 s, every module
  still runs, and its E-stop was applied.

  Then the robot drives as long again with no abuse: fallbacks_added is
  the control cycle's fallbacks (every periodic module's) during the
  scenarios minus those of that idle run. log_mb is what the run logged
  (every logger event, formatted) plus the growth of the dashboard's
  runtime directory; token_in_files counts the files readable by others,
  under the system's temporary directory and the runtime directory, that
  hold the token. cyclictest runs alongside both runs: what the machine
  did to every real-time thread.

  Summary: `edge: scenarios=N survived=K estop_ms=E fallbacks_added=F
  log_mb=L token_in_files=T`. Targets: survived = N, estop_ms ≤ 100,
  fallbacks_added ≤ 5, log_mb ≤ 20, token_in_files 0.
  """

  alias ThinkingCap.{Blackboard, Config, Dashboard, Runtime}
  alias ThinkingCap.Bench.Cyclictest
  alias ThinkingCap.Dashboard.Core.RuntimeDir
  alias ThinkingCap.Tuples
  require Tuples

  @root Path.expand("..", __DIR__)
  @examples Path.join(@root, "priv/examples")
  @flood Path.join(@root, "bench/support/edge_flood.exs")

  defmodule LogBytes do
    @moduledoc false
    # a logger handler that counts the bytes a log file would get
    def log(event, %{config: %{counter: counter}}) do
      bytes = event |> :logger_formatter.format(%{single_line: true}) |> IO.iodata_length()
      :counters.add(counter, 1, bytes)
    end
  end

  def run(args) do
    {opts, _, _} = OptionParser.parse(args, strict: [quick: :boolean])
    scale = if opts[:quick], do: 0.1, else: 1.0

    counter = :counters.new(1, [])
    :ok = :logger.add_handler(:edge_bench_bytes, LogBytes, %{config: %{counter: counter}})

    adf =
      Config.read!(Path.join(@examples, "office_sim.adf"))
      |> Map.update!(:dashboard, &Map.put(&1, :enabled, false))

    {:ok, _} = Runtime.start(adf)
    robot = adf.robot

    {:ok, info} =
      Dashboard.start(
        port: 0,
        rosbridge_port: 0,
        estop_port: 0,
        world: Path.join(@examples, "office.wdf")
      )

    runtime_dir = RuntimeDir.path()
    dir_before = dir_bytes(runtime_dir)
    modules_before = running_modules()
    await(fn -> match?(%{mode: :autonomy}, control(robot)) end, 30_000)
    Process.sleep(2_000)

    IO.puts(
      "edge: the robot #{inspect(robot)} drives; page :#{info.port}, rosbridge " <>
        ":#{info.rosbridge_port}, E-stop :#{info.estop_port}; #{length(modules_before)} modules"
    )

    n = fn count -> max(round(count * scale), 1) end

    scenarios = [
      {"connections",
       [
         ["connections", info.port, n.(10_000), "5.0"],
         ["connections", info.rosbridge_port, n.(10_000), "5.0"]
       ]},
      {"wrong_token", [["wrong_token", info.port, n.(10_000)]]},
      {"map", [["map", info.rosbridge_port, n.(1_000)]]},
      {"restarts", [["restarts", info.port, n.(200)]]},
      {"malformed", [["malformed", info.port, n.(1_000)]]}
    ]

    env = [
      {"TC_EDGE_TOKEN", info.token},
      {"TC_EDGE_ROBOT", Atom.to_string(robot)},
      {"TC_EDGE_MODULES", Enum.map_join(modules_before, ",", &Atom.to_string/1)}
    ]

    per_module_before = per_module_fallbacks()
    started = System.monotonic_time(:millisecond)
    probe = Cyclictest.start(600)

    results =
      for {name, floods} <- scenarios do
        result = scenario(name, floods, env, robot, info, modules_before)

        IO.puts(
          "  #{String.pad_trailing(name, 12)} survived=#{result.survived} " <>
            "estop_ms=#{fmt(result.estop_ms)} #{Enum.join(result.lines, "; ")}" <>
            if(result.problems == [],
              do: "",
              else: " PROBLEMS: #{Enum.join(result.problems, ", ")}"
            )
        )

        result
      end

    abuse_ms = System.monotonic_time(:millisecond) - started
    machine_abuse = Cyclictest.stop(probe)
    added = added_fallbacks(per_module_before, per_module_fallbacks())
    fallbacks_abuse = added |> Map.values() |> Enum.sum()
    abuse_by_module = for {name, n} <- added, n > 0, do: "#{inspect(name)} #{n}"

    # the same length of driving, untouched
    idle_before = per_module_fallbacks()
    probe = Cyclictest.start(600)
    Process.sleep(abuse_ms)
    machine_idle = Cyclictest.stop(probe)

    fallbacks_idle =
      idle_before |> added_fallbacks(per_module_fallbacks()) |> Map.values() |> Enum.sum()

    log_mb = (:counters.get(counter, 1) + dir_bytes(runtime_dir) - dir_before) / 1_048_576
    token_files = token_files(info.token, [System.tmp_dir!(), runtime_dir, @root])

    IO.puts(
      "  fallbacks: #{fallbacks_abuse} under abuse (#{Enum.join(abuse_by_module, ", ")}), " <>
        "#{fallbacks_idle} idle, over #{Float.round(abuse_ms / 1000, 1)} s each"
    )

    IO.puts(
      "  cyclictest max wake-up latency: #{machine_abuse.max} us under abuse, " <>
        "#{machine_idle.max} us idle (p99 #{machine_abuse.p99} / #{machine_idle.p99} us)"
    )

    if token_files != [], do: IO.puts("  token found in: #{Enum.join(token_files, ", ")}")

    :logger.remove_handler(:edge_bench_bytes)
    Dashboard.stop()

    worst =
      results |> Enum.map(& &1.estop_ms) |> Enum.reject(&is_nil/1) |> Enum.max(fn -> nil end)

    IO.puts(
      "edge: scenarios=#{length(results)} survived=#{Enum.count(results, & &1.survived)} " <>
        "estop_ms=#{fmt(worst)} fallbacks_added=#{max(fallbacks_abuse - fallbacks_idle, 0)} " <>
        "log_mb=#{Float.round(log_mb, 2)} token_in_files=#{length(token_files)}"
    )
  end

  defp scenario(_name, floods, env, robot, info, modules_before) do
    ports = Enum.map(floods, &flood(&1, env))
    Process.sleep(1_000)
    estop_ms = estop(robot, info.estop_port)
    release(robot)
    lines = Enum.map(ports, &await_flood/1)

    problems =
      [
        estop_ms == nil && "E-stop not applied",
        not page_served?(info) && "page not served after 10 s",
        running_modules() != modules_before && "modules changed"
      ]
      |> Enum.filter(& &1)

    %{survived: problems == [], problems: problems, estop_ms: estop_ms, lines: lines}
  end

  defp flood(args, env) do
    elixir = System.find_executable("elixir")
    args = [@flood | Enum.map(args, &to_string/1)]
    env = Enum.map(env, fn {k, v} -> {String.to_charlist(k), String.to_charlist(v)} end)
    Port.open({:spawn_executable, elixir}, [:binary, :exit_status, args: args, env: env])
  end

  defp await_flood(port, acc \\ "") do
    receive do
      {^port, {:data, data}} -> await_flood(port, acc <> data)
      {^port, {:exit_status, _}} -> String.trim(acc)
    after
      300_000 -> "#{acc} (still running after 5 min)"
    end
  end

  # the E-stop asked on its port; ms until the base applied it (nil: never)
  defp estop(robot, port) do
    {:ok, ref} = Blackboard.subscribe(Tuples.control(robot))
    t0 = System.monotonic_time(:microsecond)

    reply =
      with {:ok, s} <- :gen_tcp.connect({127, 0, 0, 1}, port, [:binary, active: false], 5_000),
           :ok <- :gen_tcp.send(s, "POST /estop/#{robot} HTTP/1.0\r\n\r\n"),
           do: :gen_tcp.recv(s, 0, 5_000)

    applied =
      receive do
        {:blackboard, ^ref, Tuples.control(_, %{mode: :estop})} ->
          System.monotonic_time(:microsecond)
      after
        5_000 -> nil
      end

    Blackboard.unsubscribe(ref)

    case {reply, applied} do
      {{:ok, "HTTP/1.1 200" <> _}, t} when is_integer(t) -> Float.round((t - t0) / 1000, 1)
      _ -> nil
    end
  end

  defp release(robot) do
    ThinkingCap.Dashboard.Control.estop_release(robot, :edge_bench)
    await(fn -> match?(%{mode: :autonomy}, control(robot)) end, 10_000)
  end

  defp page_served?(info) do
    await(
      fn ->
        with {:ok, s} <-
               :gen_tcp.connect({127, 0, 0, 1}, info.port, [:binary, active: false], 1_000),
             :ok <- :gen_tcp.send(s, "GET /?token=#{info.token} HTTP/1.0\r\n\r\n"),
             {:ok, "HTTP/1.1 200" <> _} <- :gen_tcp.recv(s, 0, 2_000) do
          :gen_tcp.close(s)
          true
        else
          _ -> false
        end
      end,
      10_000
    )
  end

  defp running_modules, do: Runtime.which_modules() |> Enum.map(& &1.name) |> Enum.sort()

  # fallbacks since `before`, per activity; one restarted meanwhile (a
  # restart request) counts from 0 again
  defp added_fallbacks(before, now) do
    Map.new(now, fn {name, n} ->
      b = Map.get(before, name, 0)
      {name, if(n >= b, do: n - b, else: n)}
    end)
  end

  defp per_module_fallbacks,
    do: Map.new(Runtime.timing(), fn {name, t} -> {name, Map.get(t, :fallbacks, 0)} end)

  defp control(robot) do
    case Blackboard.rdp(Tuples.control(robot)) do
      {:ok, Tuples.control(_, control)} -> control
      :none -> nil
    end
  end

  defp await(fun, timeout) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      cond do
        fun.() -> true
        System.monotonic_time(:millisecond) > deadline -> false
        true -> Process.sleep(50) && nil
      end
    end)
    |> Enum.find(&is_boolean/1)
  end

  defp dir_bytes(dir) do
    Path.wildcard(Path.join(dir, "**/*"), match_dot: true)
    |> Enum.map(fn path ->
      case File.stat(path) do
        {:ok, %{type: :regular, size: size}} -> size
        _ -> 0
      end
    end)
    |> Enum.sum()
  end

  # regular files readable by others, up to three levels down, that hold
  # the token (the repository's build output aside)
  defp token_files(token, dirs) do
    for dir <- dirs,
        depth <- ["*", "*/*", "*/*/*"],
        path <- Path.wildcard(Path.join(dir, depth), match_dot: true),
        not String.contains?(path, ["/_build/", "/node_modules/", "/.git/"]),
        match?({:ok, %{type: :regular, size: size}} when size < 50_000_000, File.stat(path)),
        Bitwise.band(File.stat!(path).mode, 0o004) != 0,
        match?({:ok, _}, File.read(path)),
        String.contains?(File.read!(path), token),
        uniq: true,
        do: path
  end

  defp fmt(nil), do: "-"
  defp fmt(x), do: x
end
