defmodule ThinkingCap.Runtime.TupleLoggerTest do
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}
  alias ThinkingCap.Testing.Cluster

  @moduletag :tmp_dir

  defp start_logger(dir, params) do
    robot = :"r#{System.unique_integer([:positive])}"
    name = :"logger_#{robot}"
    adf = Path.join(dir, "#{robot}.adf")

    File.write!(adf, """
    [robot: :#{robot}, modules: [#{name}: [module: ThinkingCap.Runtime.TupleLogger,
      activity: :background, params: #{inspect(params)}]]]
    """)

    {:ok, _} = Runtime.start(Config.read!(adf))
    on_exit(fn -> Runtime.stop(name) end)
    {robot, name}
  end

  test "logs its robot's tuples, a line each, and not another robot's", %{tmp_dir: dir} do
    log = Path.join([dir, "logs", "tc.log"])
    {robot, _name} = start_logger(dir, path: log)

    Blackboard.out({:hello, robot, %{n: 1}})
    Blackboard.out({:hello, :someone_else, %{n: 2}})
    Blackboard.out({:hello, robot, %{n: 3}})

    Cluster.wait_until(fn -> File.exists?(log) and File.read!(log) =~ "n: 3" end)
    lines = log |> File.read!() |> String.split("\n", trim: true)
    ours = Enum.filter(lines, &(&1 =~ ":hello"))
    assert [first, second] = ours
    assert first =~ ~r/^\d{13} \{:hello, :#{robot}, %\{n: 1\}\}$/
    assert second =~ "%{n: 3}"
    refute File.read!(log) =~ ":someone_else"
  end

  test "rotates the file past max_bytes and cuts long lines", %{tmp_dir: dir} do
    log = Path.join(dir, "tc.log")
    {robot, _name} = start_logger(dir, path: log, max_bytes: 1024, max_line: 100)

    for i <- 1..60, do: Blackboard.out({:big, robot, %{i: i, text: String.duplicate("x", 500)}})
    # the file may be between its rename to .1 and its new start when looked at
    Cluster.wait_until(fn ->
      File.exists?(log <> ".1") and
        case File.read(log) do
          {:ok, text} -> text =~ "i: 60"
          {:error, _} -> false
        end
    end)

    for file <- [log, log <> ".1"] do
      for line <- String.split(File.read!(file), "\n", trim: true) do
        # the time, a space, at most 100 bytes of tuple and the cut mark
        assert byte_size(line) <= 13 + 1 + 100 + byte_size("…")
      end
    end

    assert File.stat!(log <> ".1").size < 2 * 1024 + 200
  end
end
