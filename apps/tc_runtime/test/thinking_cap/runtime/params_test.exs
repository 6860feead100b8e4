defmodule ThinkingCap.Runtime.ParamsTest do
  # One module contract: the runtime (Host) and the lockstep harness read
  # modules with the same core, and live parameters. Hosts modules in this
  # node's runtime: not beside other tests.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Cycle, Runtime}
  alias ThinkingCap.Module.ActionError
  alias ThinkingCap.Test.Modules
  alias ThinkingCap.Testing.{Cluster, Lockstep}
  import ThinkingCap.Testing.Cycle

  @moduletag :tmp_dir

  defp start!(dir, module, activity \\ ":event", params \\ "[]") do
    robot = :"p#{System.unique_integer([:positive])}"
    name = :"m_#{robot}"
    path = Path.join(dir, "#{robot}.adf")

    File.write!(
      path,
      "[robot: :#{robot}, modules: [#{name}: [module: #{inspect(module)}, activity: #{activity}, params: #{params}]]]"
    )

    on_exit(fn -> Runtime.stop(name) end)
    {:ok, [%{pid: pid}]} = Runtime.start(Config.read!(path))
    %{robot: robot, name: name, pid: pid}
  end

  @periodic ":periodic, period: 0.01, deadline: 0.005"

  # the tuples of these tags a run wrote, in order, the time of a param change left out
  @tags [:ready, :poked, :param, :second_seen]
  defp comparable(tuples) do
    for {tag, _r, payload} = t <- tuples, tag in @tags do
      if tag == :param, do: put_elem(t, 2, Map.delete(payload, :at)), else: t
    end
  end

  describe "one core" do
    test "the same module in the runtime and in lockstep has the same effects", %{tmp_dir: dir} do
      robot = :"p#{System.unique_integer([:positive])}"
      name = :"scripted_#{robot}"
      {:ok, ref} = Blackboard.subscribe({:_, robot, :_})

      path = Path.join(dir, "s.adf")

      File.write!(
        path,
        "[robot: :#{robot}, modules: [#{name}: [module: ThinkingCap.Test.Modules.Scripted, activity: #{@periodic}]]]"
      )

      on_exit(fn -> Runtime.stop(name) end)
      {:ok, _} = Runtime.start(Config.read!(path))
      :ok = Cycle.subscribe(name)

      # hosted: a poke (its effects: an out, a subscription, a param the
      # module sets itself), then a tuple of the new subscription
      :ok = Blackboard.out({:poke, robot, 7})
      {:ok, _} = Blackboard.rd({:poked, robot, :_}, 2_000)
      {:ok, _} = Blackboard.rd({:param, robot, :_}, 2_000)
      :ok = Blackboard.out({:second, robot, 3})
      {:ok, _} = Blackboard.rd({:second_seen, robot, :_}, 2_000)
      # its cycles command the level it set, and see it applied
      applied_until(name, &(&1.kind == :fresh and &1.command == {:level, 7}))

      {:ok, {:applied, ^robot, {:level, 7}}} =
        Blackboard.rd({:applied, robot, {:level, 7}}, 2_000)

      Runtime.stop(name)
      hosted = for {:blackboard, ^ref, tuple} <- flush(), do: tuple
      Blackboard.unsubscribe(ref)

      # in lockstep
      lock =
        Lockstep.new(robot: robot, modules: [{name, {Modules.Scripted, [], period: 0.01}}])
        |> Lockstep.deliver({:poke, robot, 7})
        |> Lockstep.deliver({:second, robot, 3})
        |> Lockstep.advance(0.0)

      assert Lockstep.latest(lock, {:applied, robot, :_}) == {:applied, robot, {:level, 7}}
      assert Lockstep.params(lock, name) == %{level: 7}

      expected = [
        {:ready, robot, 0},
        {:poked, robot, 7},
        {:param, robot, %{module: name, key: :level, value: 7, by: {:module, name}}},
        {:second_seen, robot, {3, 7}}
      ]

      assert comparable(Lockstep.outs(lock)) == expected
      assert comparable(hosted) == expected
    end

    test "an unknown or malformed action is the same error in both, naming module and callback",
         %{tmp_dir: dir} do
      for action <- [{:outt, {:x, :y, 1}}, {:out, 42}] do
        %{robot: robot, name: name, pid: pid} = start!(dir, Modules.Scripted)

        lock = Lockstep.new(robot: robot, modules: [{name, {Modules.Scripted, []}}])

        error = assert_raise ActionError, fn -> Lockstep.deliver(lock, {:bad, robot, action}) end

        monitor = Process.monitor(pid)
        :ok = Blackboard.out({:bad, robot, action})
        assert_receive {:DOWN, ^monitor, :process, ^pid, {%ActionError{} = hosted, _stack}}, 2_000

        assert hosted.message == error.message
        assert hosted.message =~ "ThinkingCap.Test.Modules.Scripted.handle_tuple/2 returned"
        assert hosted.action == action
        # the module's supervisor starts it again
        Cluster.wait_until(fn -> Runtime.whereis(name) not in [nil, pid] end)
      end
    end
  end

  describe "live parameters" do
    test "a change reaches a periodic module within one cycle, and is recorded", %{tmp_dir: dir} do
      %{robot: robot, name: name} = start!(dir, Modules.Tunable, @periodic, "[speed: 0.3]")
      :ok = Cycle.subscribe(name)
      assert %{command: {:vel, 0.3, _}} = applied_until(name, &(&1.kind == :fresh))
      assert {:ok, %{speed: 0.3, gain: 1.0, mode: :slow, seed: 1}} = Runtime.get_params(name)

      assert :ok = Runtime.set_param(name, :speed, 0.7, by: :tester)
      _ = flush()
      # the cycle in flight may have been computed before the change: the next one was not
      fresh = fn -> applied_until(name, &(&1.kind == :fresh)) end
      _maybe_before = fresh.()
      assert %{command: {:vel, 0.7, _}} = fresh.()

      assert {:ok, %{speed: 0.7}} = Runtime.get_params(name)
      # the module's handle_param/3 ran, its actions too
      assert {:ok, {:tuned, ^robot, 0.7}} = Blackboard.rdp({:tuned, robot, :_})

      assert {:ok, {:param, ^robot, %{module: ^name, key: :speed, value: 0.7, by: :tester}}} =
               Blackboard.rdp({:param, robot, :_})

      # the latest per param stays
      :ok = Runtime.set_param(name, :speed, 0.5)
      :ok = Runtime.set_param(name, :mode, :fast)

      params =
        for {:param, ^robot, p} <- Blackboard.rd_all({:param, robot, :_}),
            do: {p.key, p.value, p.by}

      assert Enum.sort(params) == [{:mode, :fast, :api}, {:speed, 0.5, :api}]
    end

    test "refusals say why, and change nothing", %{tmp_dir: dir} do
      %{robot: robot, name: name, pid: pid} = start!(dir, Modules.Tunable)
      before = :sys.get_state(pid).mstate

      assert {:error, "speed: expected a number from 0.0 to 1.0, got 5"} =
               Runtime.set_param(name, :speed, 5)

      assert {:error, "speed: expected a number from 0.0 to 1.0, got \"fast\""} =
               Runtime.set_param(name, :speed, "fast")

      assert {:error, message} = Runtime.set_param(name, :seed, 2)
      assert message =~ "seed of ThinkingCap.Test.Modules.Tunable is read-only"

      assert {:error, message} = Runtime.set_param(name, :sped, 0.5)
      assert message =~ "no param :sped; did you mean :speed?"

      # the module's own refusal
      assert {:error, message} = Runtime.set_param(name, :gain, 7)

      assert message ==
               "ThinkingCap.Test.Modules.Tunable refused gain: a gain above 5 makes it oscillate"

      assert :sys.get_state(pid).mstate == before
      assert {:ok, %{speed: 0.2, gain: 1.0, seed: 1}} = Runtime.get_params(name)
      assert Blackboard.rd_all({:param, robot, :_}) == []

      assert {:error, "no module :no_such_module is running"} =
               Runtime.set_param(:no_such_module, :speed, 0.1)
    end

    test "a module without handle_param/3, or without declared params, takes no live changes",
         %{tmp_dir: dir} do
      %{name: declared} = start!(dir, Modules.Declared)
      assert {:error, message} = Runtime.set_param(declared, :speed, 0.5)
      assert message =~ "takes no live changes of its params (it has no handle_param/3)"

      assert {:ok, %{live: false, fields: [%{key: :speed, read_only: true}]}} =
               Runtime.describe_params(declared)

      %{name: plain} = start!(dir, Modules.Echo)
      assert {:error, message} = Runtime.set_param(plain, :speed, 0.5)
      assert message =~ "declares no params"
      assert {:ok, %{}} = Runtime.get_params(plain)
    end

    test "lockstep checks and hands changes over as the runtime does" do
      lock = Lockstep.new(robot: :r9, modules: [t: {Modules.Tunable, [speed: 0.1], period: 0.1}])
      assert {:ok, lock} = Lockstep.set_param(lock, :t, :speed, 0.9, by: :me)
      lock = Lockstep.advance(lock, 0.0)
      assert Lockstep.state(lock, :t).speed == 0.9

      assert {:param, :r9, %{module: :t, key: :speed, value: 0.9, by: :me}} =
               Lockstep.latest(lock, {:param, :r9, :_})

      assert {:tuned, :r9, 0.9} = Lockstep.latest(lock, {:tuned, :r9, :_})

      assert {:error, "speed: expected a number from 0.0 to 1.0, got -1"} =
               Lockstep.set_param(lock, :t, :speed, -1)

      assert {:error, _} = Lockstep.set_param(lock, :t, :seed, 3)
      assert {:error, _} = Lockstep.set_param(lock, :t, :gain, 9)
      assert Lockstep.params(lock, :t).gain == 1.0
    end
  end

  defp flush do
    receive do
      message -> [message | flush()]
    after
      0 -> []
    end
  end
end
