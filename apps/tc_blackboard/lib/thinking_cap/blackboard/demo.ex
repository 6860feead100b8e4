defmodule ThinkingCap.Blackboard.Demo do
  @moduledoc """
  The two-node blackboard demo (`mix tc.demo`): a second node plays the robot's sensor CPU, streaming
  a pose (latest-value tuple, 10 Hz) and posting a job every second; this
  node subscribes to the poses, takes the jobs, and prints a status line a
  second. The calling node must be distributed (`elixir --name ...`).
  """

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Testing.Cluster

  @doc """
  Runs the demo for `:seconds` (default: until the VM stops), printing with
  `:print` (default `IO.puts/1`).
  """
  @spec run(keyword()) :: :ok
  def run(opts \\ []) do
    unless Node.alive?(),
      do: raise(ArgumentError, "the demo needs a distributed node: start it with elixir --name")

    print = Keyword.get(opts, :print, &IO.puts/1)

    [sensor] = Cluster.start(1, connection: :dist)
    print.("blackboard demo: this node #{node()}, sensor node #{sensor.node}")
    print.("IEx on this node: import ThinkingCap.Blackboard.IEx; bb_ls({:pose, :_, :_})")
    Cluster.call(sensor, __MODULE__, :start_sensor, [:demo])
    {:ok, ref} = Blackboard.subscribe({:pose, :demo, :_})

    try do
      deadline = deadline(Keyword.get(opts, :seconds))
      loop(ref, print, deadline, %{poses: 0, jobs: 0, last: nil})
    after
      Cluster.stop(sensor)
    end
  end

  defp deadline(nil), do: :infinity
  defp deadline(seconds), do: System.monotonic_time(:millisecond) + seconds * 1000

  defp loop(ref, print, deadline, acc) do
    if deadline != :infinity and System.monotonic_time(:millisecond) >= deadline do
      :ok
    else
      acc = collect(ref, acc, System.monotonic_time(:millisecond) + 1000)
      acc = take_jobs(acc)
      %{x: x, y: y, theta: th} = acc.last || %{x: 0.0, y: 0.0, theta: 0.0}

      print.(
        "poses received #{acc.poses}, latest x=#{Float.round(x, 2)} y=#{Float.round(y, 2)} " <>
          "theta=#{Float.round(th, 2)}; jobs taken #{acc.jobs}; tuples on the blackboard #{length(Blackboard.rd_all({:_, :demo, :_}))}"
      )

      loop(ref, print, deadline, acc)
    end
  end

  defp collect(ref, acc, until) do
    receive do
      {:blackboard, ^ref, {:pose, :demo, pose}} ->
        collect(ref, %{acc | poses: acc.poses + 1, last: pose}, until)
    after
      max(until - System.monotonic_time(:millisecond), 0) -> acc
    end
  end

  defp take_jobs(acc) do
    case Blackboard.takep({:job, :demo, :_}) do
      {:ok, _job} -> take_jobs(%{acc | jobs: acc.jobs + 1})
      :none -> acc
    end
  end

  @doc false
  # On the sensor node: a process driving a pose round a circle at 10 Hz.
  @spec start_sensor(atom()) :: pid()
  def start_sensor(robot) do
    spawn(fn -> sensor(robot, 0) end)
  end

  defp sensor(robot, tick) do
    t = tick / 10

    pose = %{
      x: :math.cos(t / 5),
      y: :math.sin(t / 5),
      theta: t / 5 + :math.pi() / 2,
      stamp: System.os_time()
    }

    Blackboard.out({:pose, robot, pose}, key: {:pose, robot})
    if rem(tick, 10) == 0, do: Blackboard.out({:job, robot, %{n: div(tick, 10)}})
    Process.sleep(100)
    sensor(robot, tick + 1)
  end
end
