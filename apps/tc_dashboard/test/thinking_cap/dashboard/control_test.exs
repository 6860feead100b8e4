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

  defp wait_until(fun, tries \\ 200) do
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

    assert :ok = Control.restart(to_string(name), to_string(r2))
    wait_until(fn -> Runtime.whereis({r2, name}) not in [nil, p2] end)
    assert Runtime.whereis({r1, name}) == p1
  end
end
