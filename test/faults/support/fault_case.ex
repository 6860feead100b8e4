defmodule ThinkingCap.FaultSuite.Case do
  @moduledoc false
  # Shared helpers of the fault-injection suite: a robot hosted by the
  # runtime, an observer of the commands its cycle applies, and how long
  # the robot ran on a command with no next one.

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}

  @rdf """
  [
    name: "fault-diff",
    footprint: [radius: 0.2],
    kinematics: [type: :differential, wheel_radius: 0.03, wheel_separation: 0.16, max_speed: 0.5]
  ]
  """

  @doc """
  Starts an ADF on this node: a test robot's base (10 ms period, 3 ms
  deadline) plus `extra` module lines. Returns `{robot, names}`; every
  module is stopped when the test ends.
  """
  def start_robot(dir, extra \\ []) do
    robot = :"f#{System.unique_integer([:positive])}"
    File.write!(Path.join(dir, "fault.rdf"), @rdf)

    modules =
      [
        base:
          "[module: ThinkingCap.Testing.Robot, activity: :periodic, period: 0.01, deadline: 0.003, priority: 90, fallback: :stop]"
      ] ++ extra

    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}_#{robot}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")

    File.write!(
      path,
      "[\n  robot: :#{robot},\n  rdf: \"fault.rdf\",\n  modules: [\n#{body}\n  ]\n]\n"
    )

    adf = Config.read!(path)
    ExUnit.Callbacks.on_exit(fn -> for m <- adf.modules, do: Runtime.stop(m.name) end)
    {:ok, _} = Runtime.start(adf)
    {robot, Map.new(modules, fn {name, _} -> {name, :"#{name}_#{robot}"} end)}
  end

  @doc "Keeps writing an autonomous drive command for `robot` every 20 ms."
  def autonomy(robot, command \\ {:velocity, 0.2, 0.0}) do
    pid =
      spawn_link(fn ->
        Stream.repeatedly(fn ->
          Blackboard.out({:drive, robot, %{command: command}}, key: {:drive, robot})
          Process.sleep(20)
        end)
        |> Stream.run()
      end)

    ExUnit.Callbacks.on_exit(fn -> Process.exit(pid, :kill) end)
    pid
  end

  @doc """
  Starts a process recording every command applied for activity `name`
  (`ThinkingCap.Cycle.subscribe/1`, across restarts) with the time it
  arrived, in ms. It runs at high priority, beside the cycle: an
  instrument, its stamps must not wait behind the test's own work.
  """
  def observe(name) do
    parent = self()

    pid =
      spawn_link(fn ->
        Process.flag(:priority, :high)
        :ok = Cycle.subscribe(name)
        send(parent, {:observing, self()})
        observe_loop([])
      end)

    receive do
      {:observing, ^pid} -> pid
    end
  end

  defp observe_loop(acc) do
    receive do
      {:tc_cycle, :applied, _name, event} ->
        observe_loop([Map.put(event, :at, now_ms()) | acc])

      {:events, from} ->
        send(from, {:events, Enum.reverse(acc)})
        observe_loop(acc)
    end
  end

  @doc "The events an observer recorded, oldest first."
  def events(observer) do
    send(observer, {:events, self()})

    receive do
      {:events, events} -> events
    after
      5_000 -> raise "observer did not answer"
    end
  end

  @doc "Waits until the observer has recorded an event after `since` (ms) that satisfies `fun`."
  def await_event(observer, since, fun, timeout \\ 10_000) do
    ThinkingCap.Testing.Cluster.wait_until(
      fn -> Enum.any?(events(observer), &(&1.at >= since and fun.(&1))) end,
      timeout
    )

    Enum.find(events(observer), &(&1.at >= since and fun.(&1)))
  end

  @doc """
  The longest time, in ms, the robot ran on a fresh moving command before
  the next command (fresh or fallback) was applied, among the events from
  `from` ms on. Late results are not applied, so they do not count. Where
  the worker applied both commands, the time is its own (`applied_ns`):
  the reports' way to the observer adds nothing. Where the BEAM told one
  (the fallbacks of a worker's restart), it is the time between the
  observer's receipts.
  """
  def uncommanded_ms(events, from) do
    events
    |> Enum.reject(&(&1.kind == :late))
    |> Enum.drop_while(&(&1.at < from))
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.filter(fn [a, _b] -> a.kind == :fresh and a.command not in [:stop, nil] end)
    |> Enum.map(&held_ms/1)
    |> Enum.max(fn -> 0.0 end)
  end

  defp held_ms([%{applied_ns: a}, %{applied_ns: b}]) when is_integer(a) and is_integer(b),
    do: (b - a) / 1.0e6

  defp held_ms([a, b]), do: b.at - a.at

  def now_ms, do: System.monotonic_time(:microsecond) / 1000

  @doc """
  Starts the machine's own reference for a fault's window: cyclictest, a
  thread on each CPU at `SCHED_FIFO` 80 waking every millisecond (at most
  a minute; `machine_stall_ms/1` stops it).
  """
  def start_stall_probe, do: ThinkingCap.Bench.Cyclictest.start(60, 1_000)

  @doc """
  What the machine did to its real-time threads since
  `start_stall_probe/0` (a virtual machine stalls its CPUs now and then),
  the robot's included: `max_ms`, the longest a thread waited past its
  wake-up, and `late`, how many wake-ups came 3 ms (a deadline) late or
  more. Zeros without cyclictest.
  """
  def machine_stalls(probe) do
    case ThinkingCap.Bench.Cyclictest.stop(probe) do
      %{max: nil} -> %{max_ms: 0.0, late: 0}
      %{max: us, over: late} -> %{max_ms: us / 1000, late: late}
    end
  end

  # the test robot's period (start_robot/2)
  @period_ms 10

  # The least wake-up lateness allowed the worker's timing thread: it is
  # woken by the same OS as cyclictest's threads, but not at the same
  # moments. On the worker's own clock (applied_ns) a command was once held
  # 13.8 ms, 0.8 over the period and deadline, in a window where
  # cyclictest's worst wake-up was 0.4 ms late.
  @least_wakeup_ms 1.0

  @doc """
  Asserts that the robot never ran on one command for longer than
  `bound_ms` plus the machine's own worst stall in the window (`machine`
  from `machine_stalls/1`, and at least #{@least_wakeup_ms} ms): a stall of
  this shared machine's CPUs makes every real-time thread late, the
  robot's too.
  """
  def assert_uncommanded_within(uncommanded, bound_ms, machine) do
    stall = max(machine.max_ms, @least_wakeup_ms)

    ExUnit.Assertions.assert(
      uncommanded <= bound_ms + stall,
      "the robot ran #{uncommanded} ms on one command; the bound is #{bound_ms} ms " <>
        "plus the machine's own worst stall meanwhile, #{machine.max_ms} ms " <>
        "(at least #{@least_wakeup_ms})"
    )
  end

  @doc """
  Asserts that an activity of the test robot's period (10 ms) kept its
  deadline over a window of `cycles`: at most 1 % of them fell back, plus
  what the machine itself took. Each wake-up the machine made 3 ms late or
  more meanwhile (`machine.late`) may cost every cycle its stall spans:
  one, and one more for each period of the longest stall
  (`machine.max_ms`).
  """
  def assert_kept_deadline(cycles, fallbacks, machine) do
    per_stall = 1 + floor(machine.max_ms / @period_ms)
    allowed = cycles * 0.01 + machine.late * per_stall

    ExUnit.Assertions.assert(
      fallbacks <= allowed,
      "#{fallbacks} fallbacks in #{cycles} cycles (the machine woke real-time threads " <>
        "3 ms late #{machine.late} times meanwhile, #{machine.max_ms} ms at worst)"
    )
  end
end
