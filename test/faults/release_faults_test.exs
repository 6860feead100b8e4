defmodule ThinkingCap.FaultSuite.ReleaseFaultsTest do
  # The README's two-node steps, with the release itself: `mix release`
  # builds it, two daemons deploy the two-node office example (its node
  # names made unique and its dashboard on a free port), the robot
  # patrols, the brain node is killed with SIGKILL, and the base stops the
  # robot, takes over the brain's modules and carries on.
  #
  # The daemons run as a robot's would: their schedulers at real-time
  # priority where the OS grants it (rel/vm.args.eex turns busy-waiting
  # off), the timing worker above them.
  use ExUnit.Case, async: false

  alias ThinkingCap.FaultSuite.Tally

  @moduletag :faults
  @moduletag :tmp_dir
  @moduletag timeout: 600_000

  @root Path.expand("../..", __DIR__)
  @example Path.join(@root, "priv/examples/office_two_nodes.adf")
  @brain_modules [:perception, :localization, :control, :planner]
  # the waypoint the example's localizer starts at
  @dock {1.0, 1.0}

  test "a two-node release pair: the brain killed, the robot stopped, then carrying on",
       %{tmp_dir: dir} do
    rel = build_release(Path.join(dir, "rel"))
    id = System.unique_integer([:positive])
    base = :"tc_base_#{id}@127.0.0.1"
    brain = :"tc_brain_#{id}@127.0.0.1"
    adf = write_adf(dir, base, brain)
    cookie = Base.url_encode64(:crypto.strong_rand_bytes(18), padding: false)

    env = [
      {"RELEASE_COOKIE", cookie},
      {"TC_ADF", adf},
      {"TC_INTERFACE", "127.0.0.1"}
    ]

    # a weak cookie or an interface that is not this host's is refused
    # at start, saying which
    for {bad, message} <- [
          {[{"RELEASE_COOKIE", "short"}], "at least 20"},
          {[{"RELEASE_COOKIE", String.duplicate(" ", 24)}], "blanks"},
          {[{"TC_INTERFACE", "1.2.3"}], "must be an IPv4 address"},
          {[{"TC_INTERFACE", "203.0.113.77"}], "not an address of this host"}
        ] do
      env = [{"RELEASE_NODE", "tc_refused_#{id}@127.0.0.1"} | bad ++ env]
      env = Enum.uniq_by(env, &elem(&1, 0))
      assert {out, 1} = System.cmd(rel, ["daemon"], env: env, stderr_to_stdout: true)
      assert out =~ message
    end

    # whatever happens, no daemon outlives the test
    on_exit(fn -> System.cmd("pkill", ["-9", "-f", "tc_(base|brain)_#{id}@"]) end)
    observe(cookie, [base, brain])
    # the brain first: a base that finds no brain within the ADF's
    # settle (5 s; a loaded machine takes longer to start a release)
    # rightly fails the brain's modules over to itself
    daemon(rel, brain, Path.join(dir, "brain_tmp"), env)
    daemon(rel, base, Path.join(dir, "base_tmp"), env)

    # every module where the ADF puts it, and the robot driving itself
    await("the ADF's placement", 60_000, fn ->
      hosts = hosts(base)
      hosts[:base] == base and Enum.all?(@brain_modules, &(hosts[&1] == brain))
    end)

    # as a robot's: the schedulers real-time where this machine grants it
    # (it does to root; the suite's own VM tells)
    if realtime_granted?() do
      for node <- [base, brain] do
        policies = call(node, ThinkingCap.Runtime.Scheduling, :policies, [])
        schedulers = for {"" <> name, p} <- policies, name =~ "scheduler", do: p.policy
        assert schedulers != [] and Enum.all?(schedulers, &(&1 == :fifo)), inspect(policies)
      end
    end

    # the dashboard runs in a release too (yaws is part of it)
    await("the dashboard on the base node", 30_000, fn ->
      match?(%{port: port} when is_integer(port), call(base, ThinkingCap.Dashboard, :info, []))
    end)

    await("the robot under autonomy", 60_000, fn -> match?(%{mode: :autonomy}, control(base)) end)
    recorder = record_control(base)
    # well away from the dock, where the ADF starts the localizer
    await("the robot 2 m from the dock", 90_000, fn ->
      distance(sim_position(base), @dock) > 2.0
    end)

    Tally.injected()
    brain_pid = os_pid(brain)
    killed_at = System.os_time(:millisecond)
    {_, 0} = System.cmd("kill", ["-9", brain_pid])

    await("the brain's modules on the base", 30_000, fn ->
      hosts = hosts(base)
      Enum.all?(@brain_modules, &(hosts[&1] == base))
    end)

    # the localizer resumed from its handoff: its first estimate is where
    # the robot is, not back at the dock (the brain's last estimate went
    # with the brain)
    await("an estimate from the base's localizer", 30_000, fn -> estimate_position(base) end)
    assert distance(estimate_position(base), sim_position(base)) < 0.5

    # then carrying on under the base's copy of the controller
    failed_over_at = System.os_time(:millisecond)

    await(
      "the controller back",
      60_000,
      fn -> Enum.any?(after_kill(base, recorder, failed_over_at), &driving?/1) end,
      fn -> inspect(after_kill(base, recorder, killed_at), pretty: true) end
    )

    # never blind in the gap: where the controller's commands stopped
    # coming for longer than the base's command_timeout (0.3 s in the
    # example), the base stopped the robot within that time
    events = changes(base, recorder)
    drives = for {at, :drive, _} <- events, do: at
    {gap_start, gap_end} = largest_gap(drives, killed_at)

    IO.puts(
      "\nrelease pair: the controller's commands came back #{gap_end - gap_start} ms after its last"
    )

    if gap_end - gap_start > 300 do
      assert Enum.any?(events, fn {at, kind, c} ->
               kind == :control and c.command == :stop and at > gap_start and
                 at <= gap_start + 300 + 150
             end),
             "no stop within the command timeout of the last command (#{gap_end - gap_start} ms without one)"
    end

    resumed = sim_position(base)
    await("the robot moving again", 60_000, fn -> distance(sim_position(base), resumed) > 0.2 end)

    # every port the base node listens on (distribution, the dashboard) is
    # on TC_INTERFACE, none on all interfaces
    base_pid = os_pid(base)

    if System.find_executable("ss") do
      {listening, 0} = System.cmd("ss", ["-ltnpH"])
      mine = for line <- String.split(listening, "\n"), line =~ "pid=#{base_pid},", do: line
      assert mine != []
      assert Enum.all?(mine, &(&1 =~ " 127.0.0.1:")), Enum.join(mine, "\n")
    end

    # the release's stop: the node gone within 5 s of the request
    env = [
      {"RELEASE_NODE", Atom.to_string(base)},
      {"RELEASE_TMP", Path.join(dir, "base_tmp")} | env
    ]

    # `stop` boots a VM of its own to deliver the request: the 5 s count
    # from when it returns, the request delivered (on a loaded machine the
    # boot alone may take seconds)
    {_, 0} = System.cmd(rel, ["stop"], env: env, stderr_to_stdout: true)
    stop_at = System.monotonic_time(:millisecond)

    gone_at =
      Enum.find_value(1..140, fn _ ->
        Process.sleep(50)
        {_, status} = System.cmd("kill", ["-0", base_pid], stderr_to_stdout: true)
        if status != 0, do: System.monotonic_time(:millisecond)
      end)

    assert gone_at && gone_at - stop_at <= 5_000, "the base node still runs 5 s after stop"
    Tally.survived()
  end

  ## the release and its daemons

  # whether this machine lets a process take SCHED_FIFO (root, or
  # CAP_SYS_NICE): asked of chrt, on a short-lived process
  defp realtime_granted? do
    match?({_, 0}, System.cmd("chrt", ["-f", "1", "true"], stderr_to_stdout: true))
  end

  defp build_release(path) do
    {out, status} =
      System.cmd("mix", ["release", "--path", path, "--overwrite", "--quiet"],
        cd: @root,
        env: [{"MIX_ENV", "prod"}],
        stderr_to_stdout: true
      )

    assert status == 0, "mix release failed:\n#{out}"
    Path.join(path, "bin/thinking_cap")
  end

  defp daemon(rel, node, tmp, env) do
    File.mkdir_p!(tmp)
    env = [{"RELEASE_NODE", Atom.to_string(node)}, {"RELEASE_TMP", tmp} | env]
    {out, status} = System.cmd(rel, ["daemon"], env: env, stderr_to_stdout: true)
    assert status == 0, "#{node} did not start:\n#{out}"

    await("#{node} to answer", 60_000, fn -> :net_kernel.hidden_connect_node(node) end, fn ->
      daemon_log(tmp)
    end)
  end

  # what the daemon wrote (run_erl keeps its console in RELEASE_TMP/log)
  # and what epmd knows, for a daemon that never answered
  defp daemon_log(tmp) do
    logs =
      for file <- Path.wildcard(Path.join(tmp, "log/*")) do
        text = File.read!(file)
        "--- #{Path.basename(file)}:\n" <> String.slice(text, -min(byte_size(text), 4_000), 4_000)
      end

    {names, _} = System.cmd("epmd", ["-names"], stderr_to_stdout: true)
    "\n--- epmd -names:\n#{names}\n" <> Enum.join(logs, "\n")
  end

  # The example ADF with this run's node names, its description files
  # found where they are, and its dashboard on ports of its own.
  defp write_adf(dir, base, brain) do
    text =
      File.read!(@example)
      |> String.replace(~s("tc_base@127.0.0.1"), ~s("#{base}"))
      |> String.replace(~s("tc_brain@127.0.0.1"), ~s("#{brain}"))
      |> String.replace(~s(rdf: "office_robot.rdf"), ~s(rdf: "#{example("office_robot.rdf")}"))
      |> String.replace(~s(wdf: "office.wdf"), ~s(wdf: "#{example("office.wdf")}"))
      |> String.replace("port: 4000, rosbridge_port: 9090", "port: 0, rosbridge_port: 0")

    assert text =~ "#{base}" and text =~ "port: 0", "the example ADF changed: update this test"
    path = Path.join(dir, "two_nodes.adf")
    File.write!(path, text)
    path
  end

  defp example(file), do: Path.join(Path.dirname(@example), file)

  ## watching from a hidden node (not a member of the robot's cluster)

  defp observe(cookie, nodes) do
    # the release's net_ticktime (rel/vm.args.eex): with a longer one here
    # the daemons would find this node silent and drop it
    if Node.alive?() do
      :net_kernel.set_net_ticktime(4, 0)
    else
      {_, 0} = System.cmd("epmd", ["-daemon"])

      {:ok, _} =
        :net_kernel.start(:"tc_release_test_#{System.pid()}@127.0.0.1", %{
          name_domain: :longnames,
          net_ticktime: 4
        })
    end

    for node <- nodes, do: :erlang.set_cookie(node, String.to_atom(cookie))
  end

  defp call(node, m, f, a), do: :erpc.call(node, m, f, a, 10_000)

  defp os_pid(node), do: node |> call(:os, :getpid, []) |> List.to_string()

  defp hosts(node), do: call(node, ThinkingCap.Runtime.Deployment, :status, []).modules

  defp control(node) do
    case call(node, ThinkingCap.Blackboard, :rdp, [{:control, :r1, :_}]) do
      {:ok, {:control, :r1, control}} -> control
      :none -> nil
    end
  end

  defp sim_position(node) do
    {:ok, {:sim_pose, :r1, %{pose: {x, y, _}}}} =
      call(node, ThinkingCap.Blackboard, :rdp, [{:sim_pose, :r1, :_}])

    {x, y}
  end

  defp estimate_position(node) do
    case call(node, ThinkingCap.Blackboard, :rdp, [{:pose, :r1, :_}]) do
      {:ok, {:pose, :r1, %{pose: {x, y, _}}}} -> {x, y}
      :none -> nil
    end
  end

  defp distance({ax, ay}, {bx, by}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)

  # A process on the base that keeps every controller command it gets
  # (`{:drive, r1, _}`) and every change of what the base applies
  # (`{:control, r1, _}`),
  # stamped with the (one machine's) system clock: monotonic clocks differ
  # between VMs. The release does not hold this test's code: the recorder
  # module is compiled here and loaded there.
  @recorder """
  defmodule ThinkingCap.FaultSuite.ControlRecorder do
    def start(robot) do
      {:ok, _} = ThinkingCap.Blackboard.subscribe({:control, robot, :_})
      {:ok, _} = ThinkingCap.Blackboard.subscribe({:drive, robot, :_})
      loop([])
    end

    defp loop(acc) do
      receive do
        {:blackboard, _ref, {kind, _, c}} -> loop([{System.os_time(:millisecond), kind, c} | acc])
        {:changes, from} -> send(from, {:changes, Enum.reverse(acc)}) && loop(acc)
      end
    end
  end
  """

  defp record_control(node) do
    [{module, binary}] = Code.compile_string(@recorder)
    {:module, ^module} = call(node, :code, :load_binary, [module, ~c"control_recorder", binary])
    Node.spawn(node, module, :start, [:r1])
  end

  defp after_kill(node, recorder, killed_at),
    do: for({at, :control, c} <- changes(node, recorder), at > killed_at, do: {at, c})

  defp driving?({_at, %{mode: :autonomy, command: {:velocity, v, w}}}), do: v != 0 or w != 0
  defp driving?(_change), do: false

  # the longest stretch without a controller command around the kill
  defp largest_gap(drives, killed_at) do
    {before, later} = Enum.split_with(drives, &(&1 <= killed_at))
    last = List.last(before) || killed_at

    [last | later]
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.map(&List.to_tuple/1)
    |> Enum.max_by(fn {a, b} -> b - a end, fn -> {last, last} end)
  end

  defp changes(_node, recorder) do
    send(recorder, {:changes, self()})

    receive do
      {:changes, changes} -> changes
    after
      10_000 -> flunk("the control recorder did not answer")
    end
  end

  defp await(what, timeout, fun, context \\ fn -> "" end) do
    deadline = System.monotonic_time(:millisecond) + timeout
    await_until({what, context}, deadline, fun)
  end

  defp await_until({what, context} = about, deadline, fun) do
    ok =
      try do
        fun.()
      rescue
        _ -> false
      catch
        _, _ -> false
      end

    cond do
      ok ->
        :ok

      System.monotonic_time(:millisecond) > deadline ->
        flunk("timed out waiting for #{what} #{context.()}")

      true ->
        retry(about, deadline, fun)
    end
  end

  defp retry(about, deadline, fun) do
    Process.sleep(100)
    await_until(about, deadline, fun)
  end
end
