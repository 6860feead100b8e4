defmodule ThinkingCap.Dashboard.SecretsTest do
  # The access token stays secret: never in a file others may read, never
  # in a log; the dashboard's runtime files are private and go with it.
  use ThinkingCap.Dashboard.Test.Case, async: false

  alias ThinkingCap.Dashboard
  alias ThinkingCap.Dashboard.Core.RuntimeDir

  @moduletag :tmp_dir

  defp get(port, path) do
    :inets.start()
    url = ~c"http://127.0.0.1:#{port}#{path}"
    {:ok, {{_, status, _}, _headers, _body}} = :httpc.request(:get, {url, []}, [], [])
    status
  end

  # every regular file under `dir` whose content holds `secret`
  defp files_holding(dir, secret) do
    Path.wildcard(Path.join(dir, "**/*"), match_dot: true)
    |> Enum.filter(&File.regular?/1)
    |> holding(secret)
  end

  # the regular files under `dir` written since `marker` was (find(1):
  # the machine's temporary directory may hold many files of other jobs,
  # and reading them all took minutes)
  defp files_since(dir, marker) do
    {out, _status} =
      System.cmd("find", [dir, "-xdev", "-type", "f", "-newer", marker], stderr_to_stdout: false)

    out |> String.split("\n", trim: true) |> Enum.reject(&(&1 == marker))
  end

  # those of `paths` whose content holds `secret`
  defp holding(paths, secret) do
    Enum.filter(paths, fn path ->
      case File.read(path) do
        {:ok, content} -> String.contains?(content, secret)
        _ -> false
      end
    end)
  end

  test "page loads with the token leave it in no file; the runtime files are private",
       %{tmp_dir: tmp_dir} do
    # a token of this run alone, so no other file can hold it by chance
    secret = "secret-" <> Base.url_encode64(:crypto.strong_rand_bytes(18))
    # what the system's temporary directory gets from here on is checked
    marker = Path.join(tmp_dir, "marker")
    File.write!(marker, "")
    Process.sleep(20)
    Dashboard.stop()
    {:ok, info} = Dashboard.start(port: 0, rosbridge_port: nil, token: secret)

    assert get(info.port, "/?token=#{secret}") == 200
    assert get(info.port, "/assets/app.css") == 200
    assert get(info.port, "/?token=wrong-token-xyz") in [200, 401, 403]

    dir = RuntimeDir.path()
    assert %{mode: mode} = File.stat!(dir)
    assert Bitwise.band(mode, 0o777) == 0o700
    # yaws' logs go there, and hold no token
    assert files_holding(dir, secret) == []
    # nor anything the system's temporary directory got from this run
    written = files_since(System.tmp_dir!(), marker)
    assert holding(written, secret) == []
  end

  test "a flood of wrong-token requests writes nothing", %{dashboard: info} do
    dir = RuntimeDir.path()

    size = fn ->
      dir |> Path.join("**/*") |> Path.wildcard() |> Enum.map(&File.stat!(&1).size) |> Enum.sum()
    end

    before = size.()

    for i <- 1..300 do
      assert get(info.port, "/ws?token=wrong-#{i}") in [400, 401, 403]
    end

    # no access log, no line per refused request
    assert size.() - before < 4_096
  end

  test "stopping the dashboard removes its runtime files" do
    dir = RuntimeDir.path()
    assert File.dir?(dir)
    Dashboard.stop()
    refute File.exists?(dir)
  end

  test "a dashboard removes the runtime files a halted VM left", %{tmp_dir: base} do
    # a process that has exited: its PID is free
    port = Port.open({:spawn, "true"}, [:exit_status])
    {:os_pid, dead} = Port.info(port, :os_pid)
    assert_receive {^port, {:exit_status, 0}}

    stale = Path.join(base, "thinkingcap-#{dead}-AbC_d-9")
    live = Path.join(base, "thinkingcap-#{System.pid()}-XyZ")
    other = Path.join(base, "thinkingcap-#{dead}-not.this")
    for dir <- [stale, live, other], do: File.mkdir_p!(dir)
    File.write!(Path.join(stale, "report.log"), "left")

    assert RuntimeDir.sweep(base) == [stale]
    refute File.exists?(stale)
    assert File.dir?(live)
    assert File.dir?(other)
  end

  test "the token may come from a file its owner alone can read", %{tmp_dir: dir} do
    Dashboard.stop()
    file = Path.join(dir, "token")
    File.write!(file, "from-a-file-0123456789\n")

    File.chmod!(file, 0o644)
    assert {:error, message} = Dashboard.start(port: 0, rosbridge_port: nil, token_file: file)
    assert message =~ "readable by others" and message =~ file

    File.chmod!(file, 0o600)
    assert {:ok, info} = Dashboard.start(port: 0, rosbridge_port: nil, token_file: file)
    assert info.token == "from-a-file-0123456789"

    assert {:error, message} =
             (
               Dashboard.stop()
               Dashboard.start(port: 0, rosbridge_port: nil, token_file: file <> "-none")
             )

    assert message =~ "no such file"
  end
end
