defmodule ThinkingCap.Dashboard.ControlTest do
  use ExUnit.Case, async: false

  alias ThinkingCap.{Config, Runtime}
  alias ThinkingCap.Dashboard.Control

  @moduletag :tmp_dir

  defmodule Quiet do
    @moduledoc false
    use ThinkingCap.Module

    @impl true
    def init(_params, _ctx), do: {:ok, nil}
  end

  defmodule Broken do
    @moduledoc false
    # crashes at every release: its layer gives up
    use ThinkingCap.Module

    @impl true
    def handle_cycle(_release, _state), do: raise("broken sensor")
  end

  defp wait_until(fun, tries \\ 500) do
    cond do
      fun.() -> :ok
      tries == 0 -> flunk("condition not met")
      true -> Process.sleep(10) && wait_until(fun, tries - 1)
    end
  end

  test "restart names the robot when two robots run a module of the same name", %{tmp_dir: dir} do
    name = :"quiet_#{System.unique_integer([:positive])}"

    [r1, r2] =
      for _ <- 1..2 do
        robot = :"r#{System.unique_integer([:positive])}"
        path = Path.join(dir, "#{robot}.adf")

        File.write!(path, """
        [robot: :#{robot}, modules: [#{name}: [module: #{inspect(Quiet)}, activity: :event,
                                               subscribe: [{:never_sent, :_, :_}]]]]
        """)

        {:ok, _} = Runtime.start(Config.read!(path))
        robot
      end

    on_exit(fn -> for r <- [r1, r2], do: Runtime.stop({r, name}) end)
    p1 = Runtime.whereis({r1, name})
    p2 = Runtime.whereis({r2, name})

    assert {:error, message} = Control.restart(to_string(name))
    assert message =~ "name the robot"
    assert message =~ to_string(r1) and message =~ to_string(r2)
    assert Runtime.whereis({r1, name}) == p1

    assert {:error, "no module" <> _} = Control.restart(to_string(name), "no_such_robot_q7")

    {:ok, _} = ThinkingCap.Dashboard.start(port: 0, rosbridge_port: nil)
    on_exit(fn -> ThinkingCap.Dashboard.stop() end)
    wait_until(fn -> length(listed(name)) == 2 end)

    assert :ok = Control.restart(to_string(name), to_string(r2))
    wait_until(fn -> Runtime.whereis({r2, name}) not in [nil, p2] end)
    assert Runtime.whereis({r1, name}) == p1

    # the dashboard's module list counts the restart against that robot's
    wait_until(fn -> Enum.any?(listed(name), &(&1["restarts"] == 1)) end)

    assert %{to_string(r1) => 0, to_string(r2) => 1} ==
             Map.new(listed(name), &{&1["robot"], &1["restarts"]})
  end

  test "a storm of restart requests cannot exhaust the module supervisor", %{tmp_dir: dir} do
    name = :"stormy_#{System.unique_integer([:positive])}"
    robot = :"r#{System.unique_integer([:positive])}"
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [robot: :#{robot}, modules: [#{name}: [module: #{inspect(Quiet)}, activity: :event,
                                           subscribe: [{:never_sent, :_, :_}]]]]
    """)

    {:ok, _} = Runtime.start(Config.read!(path))
    on_exit(fn -> Runtime.stop({robot, name}) end)
    supervisor = ThinkingCap.Runtime.Supervision.lookup({:layer, robot, :cognitive})

    results = for _ <- 1..200, do: Control.restart(to_string(name), to_string(robot))
    assert Enum.count(results, &(&1 == :ok)) == 1
    assert {:error, message} = List.last(results)
    assert message =~ "try again"

    # the supervisor lives on, and so does the module
    assert ThinkingCap.Runtime.Supervision.lookup({:layer, robot, :cognitive}) == supervisor
    wait_until(fn -> is_pid(Runtime.whereis({robot, name})) end)
  end

  test "a module whose layer gave up is listed as given up, with its reason", %{tmp_dir: dir} do
    robot = :"r#{System.unique_integer([:positive])}"
    broken = :"broken_#{robot}"
    quiet = :"quiet_#{robot}"
    path = Path.join(dir, "#{robot}.adf")

    File.write!(path, """
    [robot: :#{robot}, modules: [
      #{broken}: [module: #{inspect(Broken)}, activity: :periodic, period: 0.01],
      #{quiet}: [module: #{inspect(Quiet)}, activity: :event, layer: :reactive]]]
    """)

    {:ok, _} = Runtime.start(Config.read!(path))
    on_exit(fn -> for m <- [broken, quiet], do: Runtime.stop({robot, m}) end)
    {:ok, _} = ThinkingCap.Dashboard.start(port: 0, rosbridge_port: nil)
    on_exit(fn -> ThinkingCap.Dashboard.stop() end)

    wait_until(fn -> match?([%{"status" => "gave_up"}], listed(broken)) end)
    assert [%{"robot" => r, "layer" => "reactive", "reason" => reason}] = listed(broken)
    assert r == to_string(robot)
    assert reason =~ "broken sensor"
    assert reason =~ "more than 5 restarts in 5 s"
    assert [%{"status" => "stopped", "reason" => "stopped with " <> _}] = listed(quiet)
  end

  # the dashboard's telemetry entries for module `name`
  defp listed(name) do
    {_version, items} = ThinkingCap.Dashboard.Telemetry.changes_since(0)

    with {_, json} <- List.keyfind(items, "modules/all", 0),
         {:ok, %{"modules" => modules}} <- ThinkingCap.Dashboard.Core.JSON.decode(json) do
      Enum.filter(modules, &(&1["name"] == to_string(name)))
    else
      _ -> []
    end
  end
end
