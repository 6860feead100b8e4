defmodule ThinkingCap.Runtime.TraceTest do
  # Hosts modules in this node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.Module.Core.Rerun
  alias ThinkingCap.Runtime.{Starting, Trace}

  @moduletag :tmp_dir

  defp adf(dir, modules) do
    robot = :"tr#{System.unique_integer([:positive])}"
    body = Enum.map_join(modules, ",\n", fn {name, spec} -> "    #{name}: #{spec}" end)
    path = Path.join(dir, "#{robot}.adf")
    File.write!(path, "[\n  robot: :#{robot},\n  modules: [\n#{body}\n  ]\n]\n")
    adf = Config.read!(path)

    on_exit(fn ->
      for m <- adf.modules, do: Runtime.stop({robot, m.name})
      drain({:_, robot, :_})
    end)

    {adf, robot}
  end

  # an ADF of one event-driven module, named after `prefix`
  defp event_module(dir, prefix, module \\ ThinkingCap.Test.Modules.Traced) do
    name = :"#{prefix}_#{System.unique_integer([:positive])}"
    {adf, robot} = adf(dir, [{name, "[module: #{inspect(module)}, activity: :event]"}])
    {adf, robot, name}
  end

  defp drain(template) do
    if Blackboard.takep(template) != :none, do: drain(template)
  end

  defp traced(robot, name, timeout \\ 2_000) do
    receive do
      {:tc_trace, ^robot, ^name, n, event} -> {n, event}
    after
      timeout -> flunk("no trace of #{inspect(name)} within #{timeout} ms")
    end
  end

  # the next traced callback of `name` whose input matches
  defp traced_input(robot, name, kind) do
    {n, {input, _outputs} = event} = traced(robot, name)
    if kind(input) == kind, do: {n, event}, else: traced_input(robot, name, kind)
  end

  defp kind(input) when is_tuple(input), do: elem(input, 0)
  defp kind(input), do: input

  test "a module's callbacks are traced: inputs, outputs, in order from init", %{tmp_dir: dir} do
    name = :"traced_#{System.unique_integer([:positive])}"

    {adf, robot} =
      adf(dir, [
        {name,
         "[module: ThinkingCap.Test.Modules.Traced, activity: :periodic, period: 0.05, " <>
           "params: [gain: 1.0]]"}
      ])

    :ok = Trace.attach(robot)
    assert self() in Trace.sinks(robot)
    {:ok, _} = Runtime.start(adf)

    # its start: the params and context it was given, what it returned
    assert {0, {{:init, info}, outputs}} = traced(robot, name)
    assert info.module == ThinkingCap.Test.Modules.Traced
    assert info.params == [gain: 1.0]
    assert info.context.robot == robot and info.context.name == name
    assert info.activity == :periodic and info.period == 0.05
    assert outputs == [{:subscribe, {:tick, robot, :_}}]

    # a tuple delivered: named by its tag and hash; the tuple it wrote too
    tick = {:tick, robot, %{n: 2}}
    Blackboard.out(tick)
    {n1, {{:tuple, ref}, outputs}} = traced_input(robot, name, :tuple)
    assert ref == {:hash, :tick, Trace.hash(tick)}
    sum = {:sum, robot, %{sum: 2.0}}
    assert outputs == [{:out, {:hash, :sum, Trace.hash(sum)}, [key: {:sum, robot}]}]

    # a release: its times, and the cycle's command
    {_n, {{:cycle, release}, outputs}} = traced_input(robot, name, :cycle)
    assert %{cycle: _, scheduled_ns: _, released_ns: _} = release
    assert [{:cycle_result, {:sum, 2.0}, nil}] = outputs

    # live param changes, taken and refused
    assert :ok = Runtime.set_param({robot, name}, :gain, 3)
    assert {_n, {{:param, :gain, 3}, []}} = traced_input(robot, name, :param)
    assert {:error, message} = Runtime.set_param({robot, name}, :gain, 11)
    assert {_n, {{:param, :gain, 11}, {:refused, ^message}}} = traced_input(robot, name, :param)

    # a crash: what it raised, then its restart from init
    Blackboard.out({:tick, robot, %{n: :crash}})
    {n2, {{:tuple, _}, raised}} = traced_input(robot, name, :tuple)
    assert raised == {:raised, :error, "** (RuntimeError) asked to crash"}
    assert n2 > n1
    assert {0, {{:init, _}, _}} = traced_input(robot, name, :init)

    # detached: nothing more
    :ok = Trace.detach(robot)
    Blackboard.out(tick)
    Process.sleep(100)
    flush = fn f -> receive do: ({:tc_trace, ^robot, _, _, _} -> f.(f)), after: (0 -> :ok) end
    flush.(flush)
    Blackboard.out(tick)
    refute_receive {:tc_trace, ^robot, _, _, _}, 200
  end

  test "the callbacks count on without gaps while traced, and rerun to the same outputs",
       %{tmp_dir: dir} do
    {adf, robot, name} = event_module(dir, "rerun")

    :ok = Trace.attach(robot)
    {:ok, _} = Runtime.start(adf)
    ticks = for n <- 1..20, do: {:tick, robot, %{n: n}}
    Enum.each(ticks, &Blackboard.out/1)
    events = for _ <- 0..20, do: traced(robot, name)
    assert Enum.map(events, &elem(&1, 0)) == Enum.to_list(0..20)

    # run again on the same inputs, out of any process: the same outputs
    by_hash = Map.new(ticks, &{Trace.hash(&1), &1})
    [{0, {{:init, info}, init_outputs}} | rest] = events
    {rerun, outcome} = Rerun.init(name, info)
    assert Rerun.traced(outcome, robot) == init_outputs

    Enum.reduce(rest, rerun, fn {_n, {{:tuple, {:hash, :tick, h}}, outputs}}, rerun ->
      {rerun, outcome} = Rerun.call(rerun, {:tuple, Map.fetch!(by_hash, h)})
      assert Rerun.traced(outcome, robot) == outputs
      rerun
    end)
  end

  # the batched lists of `name` until `count` events came: [{n, at, event}]
  defp batched(robot, name, count, acc \\ [])
  defp batched(_robot, _name, count, acc) when count <= 0, do: acc

  defp batched(robot, name, count, acc) do
    receive do
      {:tc_trace_batch, ^robot, ^name, events} ->
        assert length(events) in 1..64
        batched(robot, name, count - length(events), acc ++ events)
    after
      2_000 -> flunk("#{count} batched events of #{inspect(name)} missing")
    end
  end

  test "a batched sink gets the same events in lists, by count and by time",
       %{tmp_dir: dir} do
    {adf, robot, name} = event_module(dir, "batched")

    :ok = Trace.attach(robot)
    :ok = Trace.attach(robot, batch: true)
    assert Enum.count(Trace.sinks(robot), &(&1 == self())) == 2
    {:ok, _} = Runtime.start(adf)
    for n <- 1..150, do: Blackboard.out({:tick, robot, %{n: n}})
    plain = for _ <- 0..150, do: traced(robot, name)

    # 151 events: two full lists at once, the rest after the delay
    before = System.monotonic_time()

    lists =
      for _ <- 1..3 do
        assert_receive {:tc_trace_batch, ^robot, ^name, events}, 2_000
        events
      end

    assert Enum.map(lists, &length/1) == [64, 64, 23]
    events = Enum.concat(lists)
    assert for({n, _at, event} <- events, do: {n, event}) == plain
    ats = for {_n, at, _event} <- events, do: at
    assert ats == Enum.sort(ats) and List.last(ats) <= before
    refute_received {:tc_trace_batch, ^robot, ^name, _}

    # a crash: what it held and what it raised are sent before it goes
    Blackboard.out({:tick, robot, %{n: 1}})
    Blackboard.out({:tick, robot, %{n: :crash}})
    [{n1, _, {{:tuple, _}, [_]}}, {n2, _, {{:tuple, _}, raised}}] = batched(robot, name, 2)
    assert {n1, n2} == {151, 152}
    assert raised == {:raised, :error, "** (RuntimeError) asked to crash"}
    # restarted, from init
    assert [{0, _, {{:init, _}, _}}] = batched(robot, name, 1)

    :ok = Trace.detach(robot)
    assert Trace.sinks(robot) == []
  end

  test "a batched sink may have its robot's events held longer", %{tmp_dir: dir} do
    {adf, robot, name} = event_module(dir, "held")

    :ok = Trace.attach(robot, batch: true, max_delay_ms: 1_000)
    assert Trace.batching(robot) == {64, 1_000}
    {:ok, _} = Runtime.start(adf)
    # init; then two tuples 200 ms apart: one list, a second after the first
    assert_receive {:tc_trace_batch, ^robot, ^name, [{0, _, {{:init, _}, _}}]}, 3_000
    Blackboard.out({:tick, robot, %{n: 1}})
    Process.sleep(200)
    Blackboard.out({:tick, robot, %{n: 2}})
    refute_receive {:tc_trace_batch, ^robot, ^name, _}, 300
    assert_receive {:tc_trace_batch, ^robot, ^name, [{1, _, _}, {2, _, _}]}, 3_000

    # the last detach forgets it; a batched attach without a delay has the default
    :ok = Trace.detach(robot)
    assert Trace.batching(robot) == {64, 100}
    :ok = Trace.attach(robot, batch: true, max_delay_ms: 250)
    :ok = Trace.attach(robot, batch: true)
    assert Trace.batching(robot) == {64, 100}
    :ok = Trace.detach(robot)
  end

  test "Trace.attach/2 refuses options it does not know" do
    assert_raise ArgumentError, ~r/batch: boolean/, fn -> Trace.attach(:r1, batch: 1) end
    assert_raise ArgumentError, ~r/batch: boolean/, fn -> Trace.attach(:r1, max: 2) end

    assert_raise ArgumentError, ~r/max_delay_ms/, fn ->
      Trace.attach(:r1, batch: true, max_delay_ms: 0)
    end

    assert_raise ArgumentError, ~r/max_delay_ms/, fn ->
      Trace.attach(:r1, batch: false, max_delay_ms: 10)
    end
  end

  test "a module that says trace: false is not traced", %{tmp_dir: dir} do
    {adf, robot, _name} = event_module(dir, "untraced", ThinkingCap.Test.Modules.Untraced)

    refute Trace.traced?(ThinkingCap.Test.Modules.Untraced)
    assert Trace.traced?(ThinkingCap.Test.Modules.Traced)
    :ok = Trace.attach(robot)
    {:ok, _} = Runtime.start(adf)
    Blackboard.out({:tick, robot, %{n: 1}})
    refute_receive {:tc_trace, ^robot, _, _, _}, 300
  end

  # a listener that holds robot's start 200 ms, then says whether module
  # `name` ran by then: {:heard, announced, pid or nil}
  defp slow_listener(robot, name) do
    test = self()

    listener =
      spawn_link(fn ->
        :ok = Starting.listen()
        send(test, :listening)

        receive do
          {:tc_adf_starting, _ref, _from, ^robot, announced} = starting ->
            # nothing started yet, however long it takes
            Process.sleep(200)
            send(test, {:heard, announced, Runtime.whereis({robot, name})})
            Starting.ready(starting)
        end
      end)

    assert_receive :listening
    listener
  end

  test "the runtime waits for its listeners before it starts an ADF's modules",
       %{tmp_dir: dir} do
    {adf, robot, name} = event_module(dir, "late")

    listener = slow_listener(robot, name)
    {:ok, [%{pid: pid}]} = Runtime.start(adf)
    assert_received {:heard, announced, nil}
    assert announced.modules == [name]
    assert Runtime.whereis({robot, name}) == pid
    Process.unlink(listener)
  end

  test "a deployment waits for them too before this node starts a module", %{tmp_dir: dir} do
    {adf, robot, name} = event_module(dir, "dep")

    listener = slow_listener(robot, name)
    {:ok, deployment} = Runtime.deploy(adf)

    on_exit(fn ->
      Supervisor.terminate_child(ThinkingCap.Runtime.Supervisor, ThinkingCap.Runtime.Deployment)
      Supervisor.delete_child(ThinkingCap.Runtime.Supervisor, ThinkingCap.Runtime.Deployment)
    end)

    assert is_pid(deployment)
    assert_receive {:heard, _announced, nil}, 5_000
    ThinkingCap.Testing.Cluster.wait_until(fn -> Runtime.whereis({robot, name}) != nil end)
    Process.unlink(listener)
  end
end
