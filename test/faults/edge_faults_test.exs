defmodule ThinkingCap.FaultSuite.EdgeFaultsTest do
  # The dashboard's node runs out of file descriptors (as a flood of
  # connections from elsewhere on the host can make it): the E-stop port
  # still engages E-stops, and the web server, which exits when it cannot
  # accept, is back once descriptors are free again.
  use ExUnit.Case, async: false

  alias ThinkingCap.Blackboard
  alias ThinkingCap.FaultSuite.Tally
  alias ThinkingCap.Testing.Cluster

  @moduletag :faults

  @token "edge-fault-token-0123456789"

  # a process on `node` holding every descriptor it can open, until told
  @hog """
  spawn(fn ->
    files =
      Stream.repeatedly(fn -> File.open("/dev/null") end)
      |> Stream.take(100_000)
      |> Enum.take_while(&match?({:ok, _}, &1))

    receive do
      :release -> Enum.each(files, fn {:ok, f} -> File.close(f) end)
    end
  end)
  """

  defp http(port, text) do
    case :gen_tcp.connect({127, 0, 0, 1}, port, [:binary, active: false], 2_000) do
      {:ok, socket} ->
        :ok = :gen_tcp.send(socket, text)
        reply = read_all(socket, "")
        :gen_tcp.close(socket)
        reply

      {:error, reason} ->
        {:error, reason}
    end
  end

  defp read_all(socket, acc) do
    case :gen_tcp.recv(socket, 0, 3_000) do
      {:ok, data} -> read_all(socket, acc <> data)
      {:error, _closed} -> acc
    end
  end

  defp page(info), do: http(info.port, "GET /?token=#{@token} HTTP/1.0\r\n\r\n")

  test "descriptors run out on the dashboard's node: E-stop still served, web server back" do
    [node] = Cluster.start(1, apps: [:tc_dashboard], max_fds: 512, log_level: :emergency)
    on_exit(fn -> Cluster.stop(node) end)

    opts = [port: 0, rosbridge_port: 0, estop_port: 0, token: @token]
    {:ok, info} = Cluster.call(node, ThinkingCap.Dashboard, :start, [opts])
    robot = :"ef#{System.unique_integer([:positive])}"
    :ok = Cluster.call(node, Blackboard, :out, [{:robot, robot, %{}}, [key: {:robot, robot}]])
    assert "HTTP/1.1 200" <> _ = page(info)

    listener = Cluster.call(node, Process, :whereis, [ThinkingCap.Dashboard.Core.EstopListener])
    Tally.injected()
    {hog, _} = Cluster.call(node, Code, :eval_string, [@hog])
    Process.sleep(500)

    # the web server cannot accept: it exits (it did for good before the
    # watchdog), and the page is unreachable
    Cluster.wait_until(fn -> not match?("HTTP/1.1 200" <> _, page(info)) end)

    # the E-stop port gives up a spare descriptor and serves. If not, the
    # listener's state says why (it showed the spare taken by the web
    # server's watchdog, before the listener kept four and gave one up
    # only for an accept that does not wait)
    answer = http(info.estop_port, "POST /estop/#{robot} HTTP/1.0\r\n\r\n")

    unless match?("HTTP/1.1 200" <> _, answer) do
      now = Cluster.call(node, Process, :whereis, [ThinkingCap.Dashboard.Core.EstopListener])
      what = [:status, :current_stacktrace, :message_queue_len, :dictionary]
      engaged = Cluster.call(node, Blackboard, :rdp, [{:estop, robot, :_}])

      flunk("""
      the E-stop port answered #{inspect(answer)}
      listener before #{inspect(listener)}, now #{inspect(now)}: \
      #{inspect(Cluster.call(node, Process, :info, [now || listener, what]))}
      engaged: #{inspect(engaged)}
      """)
    end

    assert {:ok, {:estop, ^robot, %{engaged: true, by: :estop_port}}} =
             Cluster.call(node, Blackboard, :rdp, [{:estop, robot, :_}])

    # descriptors free again: the page is served within seconds
    Cluster.call(node, Kernel, :send, [hog, :release])
    Cluster.wait_until(fn -> match?("HTTP/1.1 200" <> _, page(info)) end, 15_000)

    # and the E-stop port took its spare back
    assert "HTTP/1.1 200" <> _ = http(info.estop_port, "POST /estop HTTP/1.0\r\n\r\n")
    Tally.survived()
  end
end
