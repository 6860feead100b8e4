defmodule ThinkingCap.Bench.Blackboard do
  @moduledoc """
  `mix tc.bench blackboard`: the blackboard against the BEAM's own
  messaging and against Redis pub/sub, in one run.

    1. local out -> subscriber latency, 1,000 subscriptions over 100 tags
       (10 robot ids each), beside a raw `send` from the writer to the same
       subscriber process: on a lone node (the summary figures), with
       latest-value writes (`key: {tag, robot}`, as robots write poses and
       scans), then again with a peer node connected;
    2. cross-node out -> subscriber latency beside a raw `send` to the same
       subscriber process on the other node;
    3. Redis PUBLISH -> subscriber latency (local redis-server, eredis);
    4. out, rd and take operations per second on one node;
    5. exactly-once: 100,000 tuples taken by 8 takers on each of 2 nodes.
  """

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Bench.{Probe, Stats}
  alias ThinkingCap.Testing.Cluster

  @samples 20_000
  @warmup 2_000
  @tags 100
  @robots 10
  @ops 200_000
  @exactly_once_tuples 100_000
  @takers_per_node 8

  def run(_args) do
    Process.flag(:trap_exit, true)
    start_distribution()

    IO.puts(
      "ThinkingCap blackboard benchmark (#{System.schedulers_online()} schedulers, OTP #{System.otp_release()})\n"
    )

    # local figures on a lone node first, then again with a peer connected
    # (every write then also goes to the replicator and the other VM)
    local = local_latency()
    # robot data is written as latest-value streams (key: {tag, robot})
    keyed = local_latency(keyed: true)
    [peer] = Cluster.start(1, connection: :dist)
    local_with_peer = local_latency()
    cross = cross_latency(peer)
    redis = redis_latency()

    Stats.print_header("µs")
    Stats.print_row("blackboard local out->subscriber", local.bb)
    Stats.print_row("raw send, local", local.send)
    Stats.print_row("  same, keyed writes (latest value)", keyed.bb)
    Stats.print_row("  raw send, same run", keyed.send)
    Stats.print_row("  same, with a peer node connected", local_with_peer.bb)
    Stats.print_row("  raw send, same run", local_with_peer.send)
    Stats.print_row("blackboard cross-node", cross.bb)
    Stats.print_row("raw send, cross-node", cross.send)
    if redis, do: Stats.print_row("redis PUBLISH->subscriber", redis)

    ops = ops_per_second()

    IO.puts(
      "\none node, one process: out #{round(ops.out)}/s, rd #{round(ops.rd)}/s, take #{round(ops.take)}/s"
    )

    once = exactly_once(peer)

    IO.puts(
      "exactly-once: #{@exactly_once_tuples} tuples, #{@takers_per_node} takers on each of 2 nodes: " <>
        "taken #{once.taken}, lost #{once.lost}, duplicated #{once.duplicated} in #{once.seconds} s"
    )

    Cluster.stop(peer)
    IO.puts("")

    Stats.print_summary("blackboard",
      local_p50_us: local.bb.p50,
      send_p50_us: local.send.p50,
      local_ratio: local.bb.p50 / local.send.p50,
      cross_p50_us: cross.bb.p50,
      cross_send_p50_us: cross.send.p50,
      cross_ratio: cross.bb.p50 / cross.send.p50,
      redis_p50_us: if(redis, do: redis.p50, else: "n/a"),
      out_per_s: round(ops.out),
      taken: once.taken,
      lost: once.lost,
      duplicated: once.duplicated
    )
  end

  defp start_distribution do
    {_, 0} = System.cmd("epmd", ["-daemon"])

    unless Node.alive?() do
      {:ok, _} =
        :net_kernel.start([
          :"tc_bench_#{System.pid()}@127.0.0.1",
          :longnames
        ])

      Node.set_cookie(:"bench_#{:rand.uniform(1_000_000_000)}")
    end
  end

  ## 1. local latency, with 1,000 subscriptions over 100 tags

  defp local_latency(opts \\ []) do
    me = self()
    keyed? = Keyword.get(opts, :keyed, false)

    # 100 stream tags x 10 robots, one subscriber process per stream
    # ({tag, robot, :_}): each out is matched against the 10 subscriptions
    # of its tag and wakes one. The raw send goes to that same process.
    subscribers =
      for t <- 1..@tags, r <- 1..@robots, into: %{} do
        {{t, r}, Probe.subscriber({tag(t), r, :_}, me, :bb)}
      end

    samples =
      for k <- 1..(@samples + @warmup) do
        stream = {t, r} = {rem(k, @tags) + 1, rem(div(k, @tags), @robots) + 1}

        pair(
          k,
          fn ->
            if keyed?,
              do: Blackboard.out({tag(t), r, Probe.now_ns()}, key: {tag(t), r}),
              else: Blackboard.out({tag(t), r, Probe.now_ns()})
          end,
          fn -> send(subscribers[stream], {:raw, Probe.now_ns()}) end
        )
      end
      |> Enum.drop(@warmup)

    Enum.each(subscribers, fn {_, pid} -> send(pid, :stop) end)
    %{bb: micro(Enum.map(samples, &elem(&1, 0))), send: micro(Enum.map(samples, &elem(&1, 1)))}
  end

  defp tag(t), do: :"bench_tag_#{t}"

  ## 2. cross-node latency

  defp cross_latency(peer) do
    me = self()
    sub = Cluster.call(peer, Probe, :subscriber, [{:cross, :_, :_}, me, :bb])
    # the replication path must be up before timing it
    Cluster.wait_until(fn -> Blackboard.Core.Server.peers() != [] end)

    samples =
      for k <- 1..(@samples + @warmup) do
        pair(
          k,
          fn -> Blackboard.out({:cross, :bench, Probe.now_ns()}) end,
          fn -> send(sub, {:raw, Probe.now_ns()}) end
        )
      end
      |> Enum.drop(@warmup)

    send(sub, :stop)
    %{bb: micro(Enum.map(samples, &elem(&1, 0))), send: micro(Enum.map(samples, &elem(&1, 1)))}
  end

  ## 3. Redis pub/sub

  defp redis_latency do
    case System.find_executable("redis-server") do
      nil ->
        IO.puts("redis-server not found: run bin/setup")
        nil

      exe ->
        port_number = free_port()
        # redis-server does not notice its port closing: the shell kills it
        # when its stdin closes, which happens however this VM ends
        script =
          "#{exe} --port #{port_number} --save '' --appendonly no --bind 127.0.0.1 >/dev/null & " <>
            "r=$!; read _; kill $r"

        port = Port.open({:spawn_executable, "/bin/sh"}, [:binary, args: ["-c", script]])

        try do
          measure_redis(port_number)
        after
          Port.close(port)
        end
    end
  end

  defp free_port do
    {:ok, socket} = :gen_tcp.listen(0, ip: {127, 0, 0, 1})
    {:ok, port} = :inet.port(socket)
    :gen_tcp.close(socket)
    port
  end

  defp measure_redis(redis_port) do
    await_port(redis_port, 100)
    {:ok, publisher} = :eredis.start_link(~c"127.0.0.1", redis_port)
    {:ok, subscriber} = :eredis_sub.start_link(~c"127.0.0.1", redis_port, ~c"")
    me = self()

    listener =
      spawn(fn ->
        :ok = :eredis_sub.controlling_process(subscriber)
        :eredis_sub.subscribe(subscriber, ["bench"])
        redis_loop(subscriber, me)
      end)

    receive do
      :redis_subscribed -> :ok
    after
      5000 -> raise "redis subscription not confirmed"
    end

    samples =
      for _ <- 1..(@samples + @warmup) do
        {:ok, _} = :eredis.q(publisher, ["PUBLISH", "bench", Integer.to_string(Probe.now_ns())])
        await_latency(:redis)
      end
      |> Enum.drop(@warmup)

    Process.exit(listener, :kill)
    :eredis_sub.stop(subscriber)
    :eredis.stop(publisher)
    micro(samples)
  end

  defp redis_loop(subscriber, report_to) do
    receive do
      {:subscribed, _channel, ^subscriber} ->
        send(report_to, :redis_subscribed)
        :eredis_sub.ack_message(subscriber)

      {:message, _channel, payload, ^subscriber} ->
        send(report_to, {:latency, :redis, Probe.now_ns() - String.to_integer(payload)})
        :eredis_sub.ack_message(subscriber)
    end

    redis_loop(subscriber, report_to)
  end

  defp await_port(port, tries) do
    case :gen_tcp.connect(~c"127.0.0.1", port, [], 100) do
      {:ok, socket} ->
        :gen_tcp.close(socket)

      {:error, _} when tries > 0 ->
        Process.sleep(50)
        await_port(port, tries - 1)

      {:error, reason} ->
        raise "redis-server did not open port #{port}: #{inspect(reason)}"
    end
  end

  ## 4. operations per second

  defp ops_per_second do
    out = rate(fn -> for i <- 1..@ops, do: Blackboard.out({:ops, i, :x}) end)
    rd = rate(fn -> for i <- 1..@ops, do: {:ok, _} = Blackboard.rdp({:ops, i, :_}) end)
    take = rate(fn -> for _ <- 1..@ops, do: {:ok, _} = Blackboard.takep({:ops, :_, :_}) end)
    %{out: out, rd: rd, take: take}
  end

  defp rate(fun) do
    {us, _} = :timer.tc(fun)
    @ops / (us / 1_000_000)
  end

  ## 5. exactly-once take across two nodes

  defp exactly_once(peer) do
    half = div(@exactly_once_tuples, 2)
    template = {:once, :_, :_}
    started = System.monotonic_time(:millisecond)

    remote_takers =
      Task.async(fn ->
        Cluster.call(peer, Probe, :take_all, [template, @takers_per_node, 3000], :infinity)
      end)

    local_takers = Task.async(fn -> Probe.take_all(template, @takers_per_node, 3000) end)

    writers = [
      Task.async(fn -> Probe.write(:once, 1..half) end),
      Task.async(fn ->
        Cluster.call(peer, Probe, :write, [:once, (half + 1)..@exactly_once_tuples], :infinity)
      end)
    ]

    Enum.each(writers, &Task.await(&1, :infinity))
    taken = Task.await(remote_takers, :infinity) ++ Task.await(local_takers, :infinity)
    seconds = (System.monotonic_time(:millisecond) - started - 3000) / 1000

    unique = taken |> Enum.map(fn {_node, i} -> i end) |> MapSet.new()
    lost = Enum.count(1..@exactly_once_tuples, &(not MapSet.member?(unique, &1)))

    %{
      taken: length(taken),
      lost: lost,
      duplicated: length(taken) - MapSet.size(unique),
      seconds: seconds
    }
  end

  ## helpers

  # One blackboard and one raw sample to the same process. Whichever goes
  # first may find the receiver cold (asleep on the other scheduler), so
  # the order alternates.
  defp pair(k, out, raw) do
    if rem(k, 2) == 0 do
      out.()
      bb = await_latency(:bb)
      raw.()
      {bb, await_latency(:send)}
    else
      raw.()
      send_ns = await_latency(:send)
      out.()
      {await_latency(:bb), send_ns}
    end
  end

  defp await_latency(tag) do
    receive do
      {:latency, ^tag, ns} -> ns
      {:EXIT, _pid, :normal} -> await_latency(tag)
      {:EXIT, pid, reason} -> raise "#{inspect(pid)} exited: #{inspect(reason)}"
    after
      10_000 -> raise "no #{tag} sample within 10 s"
    end
  end

  defp micro(ns_samples), do: ns_samples |> Enum.map(&(&1 / 1000)) |> Stats.summarize()
end
