defmodule ThinkingCap.BlackBox.KilledVMTest do
  # A VM recording a robot is killed with SIGKILL: its file must read up
  # to its last chunk.
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Test.Topics
  alias ThinkingCap.MCAP.Reader

  @moduletag :tmp_dir
  @moduletag timeout: 120_000

  @script ~S"""
  [dir] = System.argv()
  # never outlive the test: gone when the test's end of the pipe closes,
  # and after a minute in any case
  spawn(fn -> IO.read(:stdio, :line) && System.halt(1) end)
  spawn(fn -> Process.sleep(60_000) && System.halt(1) end)
  {:ok, _} = Application.ensure_all_started(:tc_blackbox)
  {:ok, _} = ThinkingCap.BlackBox.record(:victim, dir: dir, chunk_seconds: 0.05)
  IO.puts("os_pid #{System.pid()}")

  Stream.iterate(1, &(&1 + 1))
  |> Enum.each(fn i ->
    ThinkingCap.Blackboard.out({:drive, :victim, %{command: {:velocity, 0.1, 0.0}, i: i}})
    if rem(i, 10) == 0, do: Process.sleep(2)
  end)
  """

  test "a killed VM leaves a file readable up to its last chunk", %{tmp_dir: dir} do
    script = Path.join(dir, "victim.exs")
    File.write!(script, @script)
    recordings = Path.join(dir, "recordings")

    paths =
      Enum.flat_map(
        Path.wildcard(Path.join(Mix.Project.build_path(), "lib/*/ebin")),
        &["-pa", &1]
      )

    port =
      Port.open({:spawn_executable, System.find_executable("elixir")}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        {:line, 1024},
        args: paths ++ [script, recordings],
        env: [{~c"ELIXIR_ERL_OPTIONS", ~c"+sbwt none +sbwtdcpu none +sbwtdio none"}]
      ])

    os_pid = await_os_pid(port)
    on_exit(fn -> System.cmd("kill", ["-KILL", os_pid], stderr_to_stdout: true) end)
    # it records: chunks reach the disk while it runs
    seen = await_file(recordings, 500)

    {_, 0} = System.cmd("kill", ["-KILL", os_pid])
    assert_receive {^port, {:exit_status, 137}}, 10_000

    assert [file] = Path.wildcard(Path.join(recordings, "*.mcap"))
    assert {:ok, mcap} = Reader.read(file)
    assert mcap.mode == :linear and mcap.truncated
    assert mcap.chunks >= 1
    assert length(mcap.messages) >= seen

    # every message written up to the last chunk reads back, in order.
    # The recorder may drop tuples when it falls far behind (a loaded
    # machine); it never skips a sequence number among those it wrote,
    # on either channel (Foxglove's JSON, the tuple whole)
    by_channel = Enum.group_by(mcap.messages, & &1.channel_id)
    assert map_size(by_channel) == 2

    for {_channel, messages} <- by_channel do
      sequences = Enum.map(messages, & &1.sequence)
      assert sequences == Enum.to_list(1..length(sequences))
    end

    ids =
      for m <- Topics.messages(mcap, "json") do
        %{"payload" => %{"i" => i}} = :jiffy.decode(m.data, [:return_maps])
        i
      end

    assert hd(ids) == 1
    assert ids == Enum.sort(Enum.uniq(ids))

    whole = for m <- Topics.messages(mcap, "etf"), do: :erlang.binary_to_term(m.data)

    assert Enum.map(whole, fn {:drive, :victim, %{i: i}} -> i end) ==
             Enum.take(ids, length(whole))
  end

  defp await_os_pid(port) do
    receive do
      {^port, {:data, {:eol, "os_pid " <> pid}}} -> pid
      {^port, {:data, _other}} -> await_os_pid(port)
      {^port, {:exit_status, status}} -> flunk("the recording VM exited with #{status}")
    after
      60_000 -> flunk("the recording VM did not start")
    end
  end

  # waits until the file being written reads with at least `n` messages
  defp await_file(dir, n, tries \\ 500) do
    seen =
      with [file] <- Path.wildcard(Path.join(dir, "*.mcap")),
           {:ok, mcap} <- Reader.read(file) do
        length(mcap.messages)
      else
        _ -> 0
      end

    cond do
      seen >= n -> seen
      tries == 0 -> flunk("the file holds #{seen} messages")
      true -> Process.sleep(20) && await_file(dir, n, tries - 1)
    end
  end
end
