defmodule ThinkingCap.Dashboard.TeleopTest do
  # The whole path without a browser: an ADF that enables the dashboard
  # starts it with a simulated robot; a client on the page's socket drives
  # the robot by hand, lets go, and stops it with the E-stop.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Dashboard, Runtime}
  alias ThinkingCap.Dashboard.Test.WSClient

  @moduletag :tmp_dir
  @examples Path.expand("../../../../../priv/examples", __DIR__)

  setup %{tmp_dir: dir} do
    robot = :"tele#{System.unique_integer([:positive])}"
    path = Path.join(dir, "teleop.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{@examples}/office.wdf",
      dashboard: [enabled: true, port: 0, rosbridge_port: 0],
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                         deadline: 0.005, fallback: :stop, params: [at: :dock, seed: 3]]
      ]
    ]
    """)

    {:ok, _} = Runtime.start(path)

    on_exit(fn ->
      Runtime.stop(:"base_#{robot}")
      Dashboard.stop()
      # a stopped driver leaves its robot in the world: take it out
      with {:ok, sim} <- ThinkingCap.Sim.Worlds.lookup("#{@examples}/office.wdf"),
           do: ThinkingCap.Sim.remove_robot(sim, robot)
    end)

    {:ok, info} = Dashboard.await(10_000)
    %{robot: robot, info: info}
  end

  test "an ADF that enables the dashboard starts it; a client drives the robot by hand", ctx do
    name = Atom.to_string(ctx.robot)
    assert ctx.info.url =~ ~r"^http://127\.0\.0\.1:\d+/\?token=[\w-]{16,}$"

    {:ok, client} = WSClient.connect("127.0.0.1", ctx.info.port, "/ws?token=#{ctx.info.token}")

    {:ok, welcome, client} = WSClient.recv_json_until(client, &(&1["op"] == "welcome"))
    assert welcome["control"]
    assert name in welcome["robots"]
    assert Enum.any?(welcome["world"]["waypoints"], &(&1["name"] == "dock"))

    {x0, y0} = position(ctx.robot)

    # held: the page refreshes the command every 100 ms
    client = hold(client, name, 0.3, 0.0, 1_000)
    assert %{mode: :teleop, command: {:velocity, v, _}} = control(ctx.robot)
    assert v > 0
    {x1, y1} = position(ctx.robot)
    assert :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2) > 0.1

    # let go without a release: the deadman rule stops it
    wait_for(fn -> match?(%{mode: :idle, command: :stop}, control(ctx.robot)) end, 1_500)
    # braking within its acceleration limit, it comes to rest
    wait_for(fn -> speed(ctx.robot) < 0.005 end, 2_000)
    Process.sleep(150)
    still = position(ctx.robot)
    Process.sleep(300)
    assert_close(position(ctx.robot), still, 0.01)

    # the E-stop beats teleoperation held
    send_json(client, %{op: "estop", robot: name})
    client = hold(client, name, 0.3, 0.0, 400)
    assert %{mode: :estop, command: :stop} = control(ctx.robot)

    send_json(client, %{op: "estop_release", robot: name})
    _client = hold(client, name, 0.3, 0.0, 400)
    assert %{mode: :teleop} = control(ctx.robot)
  end

  defp hold(client, name, v, w, ms) do
    send_json(client, %{
      op: "teleop",
      robot: name,
      v: v,
      w: w,
      sent_at: System.os_time(:millisecond)
    })

    Process.sleep(100)
    if ms > 100, do: hold(client, name, v, w, ms - 100), else: client
  end

  defp send_json(client, map), do: :ok = WSClient.send_text(client, :jiffy.encode(map))

  defp position(robot) do
    {:ok, {:sim_pose, ^robot, %{pose: {x, y, _}}}} = Blackboard.rd({:sim_pose, robot, :_}, 2_000)
    {x, y}
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

  defp wait_for(fun, timeout) do
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

  defp assert_close({x1, y1}, {x2, y2}, tol),
    do:
      assert(
        abs(x1 - x2) < tol and abs(y1 - y2) < tol,
        "#{inspect({x1, y1})} moved from #{inspect({x2, y2})}"
      )
end
