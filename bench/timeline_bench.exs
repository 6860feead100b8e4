defmodule ThinkingCap.Bench.Timeline do
  @moduledoc """
  `mix tc.bench timeline [--seconds S] [--frames N]`: the black box in
  the dashboard, on the README's main job (the office robot patrolling
  with perception, MCL, the map builder, the Blender and the planner),
  its black box on, for S seconds (default 60, the black box's minute).

    * **Opening a timeline** (`ThinkingCap.Dashboard.Timeline.open/2`):
      the ms to take the snapshot from the ring buffer and index it, the
      tuples it holds, and the memory of the process that holds it.
    * **Frames**: N instants (default 300) at random in the snapshot, each
      asked for as the page does (the map it has sent back): the µs a
      frame takes (p50, p99) and its bytes (p50, max), and the bytes of a
      frame that carries the map. The page's slider asks for one frame at
      a time, so p99 bounds how far behind the thumb the map is.
    * **Download**: a dump written (`ThinkingCap.BlackBox.dump/3`) and
      fetched over HTTP from the dashboard's `/dumps/ROBOT/NAME` with the
      token, streamed in chunks: its size and MB/s on loopback.

  Summary: `timeline: open_ms=… tuples=… held_mb=… frame_p50_us=…
  frame_p99_us=… frame_bytes_p50=… map_frame_bytes=… download_mb_s=…`.
  """

  alias ThinkingCap.{BlackBox, Blackboard, Dashboard, Runtime}
  alias ThinkingCap.Dashboard.Timeline
  alias ThinkingCap.Tuples
  require Tuples

  @root Path.expand("..", __DIR__)
  @examples Path.join(@root, "priv/examples")
  @robot :tl1

  def run(args) do
    {opts, _, _} = OptionParser.parse(args, strict: [seconds: :float, frames: :integer])
    seconds = opts[:seconds] || 60.0
    n_frames = opts[:frames] || 300
    dir = Path.join(System.tmp_dir!(), "tc_timeline_bench_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)

    try do
      modules = start_robot(dir)

      IO.puts(
        "timeline: the office robot patrolling (#{length(modules)} modules), " <>
          "its black box on, for #{seconds} s"
      )

      Process.sleep(round(seconds * 1000))
      pid = BlackBox.ring_buffer(@robot)
      info = ThinkingCap.BlackBox.RingBuffer.info(pid)

      IO.puts(
        "  ring buffer: #{info.messages} tuples, #{mb(info.bytes)} MB (external size), " <>
          "#{info.dropped} dropped"
      )

      {open_us, {:ok, timeline, summary}} = :timer.tc(fn -> Timeline.open(@robot, self()) end)
      tuples = summary.streams |> Map.values() |> Enum.sum()
      {:memory, held} = Process.info(timeline, :memory)

      IO.puts(
        "  open: #{fmt(open_us / 1000, 1)} ms, #{tuples} tuples of " <>
          "#{map_size(summary.streams)} streams over #{fmt((summary.to - summary.from) / 1000, 1)} s, " <>
          "held in #{mb(held)} MB"
      )

      IO.puts(
        "    " <> Enum.map_join(Enum.sort(summary.streams), ", ", fn {k, n} -> "#{k} #{n}" end)
      )

      {times, sizes, map_bytes} = frames(timeline, summary, n_frames)
      Timeline.close(timeline)
      times = Enum.sort(times)
      sizes = Enum.sort(sizes)

      IO.puts(
        "  frames (#{n_frames}, the page's map sent back): p50 #{pctl(times, 50)} µs, " <>
          "p99 #{pctl(times, 99)} µs, max #{List.last(times)} µs; " <>
          "#{pctl(sizes, 50)} B p50, #{List.last(sizes)} B max; with the map: #{map_bytes} B"
      )

      {bytes, mb_s} = download(dir)
      IO.puts("  download: a dump of #{mb(bytes)} MB at #{fmt(mb_s, 1)} MB/s (loopback)")

      IO.puts(
        "timeline: open_ms=#{fmt(open_us / 1000, 1)} tuples=#{tuples} held_mb=#{mb(held)} " <>
          "frame_p50_us=#{pctl(times, 50)} frame_p99_us=#{pctl(times, 99)} " <>
          "frame_bytes_p50=#{pctl(sizes, 50)} map_frame_bytes=#{map_bytes} " <>
          "download_mb_s=#{fmt(mb_s, 1)}"
      )
    after
      Dashboard.stop()
      BlackBox.forget(@robot)
      for name <- modules(), do: Runtime.stop(name)
      File.rm_rf!(dir)
    end
  end

  defp modules,
    do: ~w(base perception localization mapper control planner)a |> Enum.map(&:"#{&1}_tl")

  # priv/examples/office_sim.adf, without its dashboard, with the black box
  defp start_robot(dir) do
    path = Path.join(dir, "office.adf")
    [base, perception, localization, mapper, control, planner] = modules()

    File.write!(path, """
    [
      robot: #{inspect(@robot)},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{@examples}/office.wdf",
      black_box: [enabled: true, dir: "#{dir}"],
      modules: [
        #{base}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                  deadline: 0.003, priority: 90, fallback: :stop, params: [at: :dock, seed: 1]],
        #{perception}: [module: ThinkingCap.Perception.Fuser, activity: :event, layer: :reactive],
        #{localization}: [module: ThinkingCap.Navigation.MCL, activity: :event,
                          params: [initial: :dock, initial_sigma: {0.1, 0.05}]],
        #{mapper}: [module: ThinkingCap.Navigation.Mapper, activity: :event],
        #{control}: [module: ThinkingCap.Control.Blender, activity: :periodic, period: 0.1,
                     deadline: 0.05, priority: 80],
        #{planner}: [module: ThinkingCap.Planner.Monitor, layer: :cognitive, activity: :periodic,
                     period: 0.5, deadline: 0.4, priority: 20,
                     params: [task: {:patrol, [:lab_bench, :desk_a, :hall_east, :dock]}]]
      ]
    ]
    """)

    {:ok, started} = Runtime.start(path)
    {:ok, _} = Blackboard.rd(Tuples.sim_pose(@robot), 10_000)
    # the launcher starts the black box from the ADF's announcement
    wait_for(fn -> BlackBox.ring_buffer(@robot) end)
    started
  end

  # frames at random instants, each sending back the map the last gave
  defp frames(timeline, summary, n) do
    :rand.seed(:exsss, {1, 2, 3})

    {times, sizes, _map, map_bytes} =
      Enum.reduce(1..n, {[], [], nil, 0}, fn _, {times, sizes, have, map_bytes} ->
        at = summary.from + :rand.uniform(max(summary.to - summary.from, 1))
        {us, {:ok, body}} = :timer.tc(fn -> Timeline.frame(timeline, at, have) end)
        {:ok, frame} = ThinkingCap.Dashboard.Core.JSON.decode("{" <> body <> "}")
        carries_map = Map.has_key?(frame["items"], "map/#{@robot}")
        map_bytes = if carries_map, do: max(map_bytes, byte_size(body)), else: map_bytes
        sizes = if carries_map, do: sizes, else: [byte_size(body) | sizes]
        {[us | times], sizes, frame["map"], map_bytes}
      end)

    {times, if(sizes == [], do: [0], else: sizes), map_bytes}
  end

  defp download(_dir) do
    token = Base.url_encode64(:crypto.strong_rand_bytes(12), padding: false)
    {:ok, info} = Dashboard.start(port: 0, rosbridge_port: nil, token: token)
    {:ok, path} = BlackBox.dump(@robot, "bench")
    :inets.start()
    url = ~c"http://127.0.0.1:#{info.port}/dumps/#{@robot}/#{Path.basename(path)}?token=#{token}"

    {us, {:ok, {{_, 200, _}, _headers, body}}} =
      :timer.tc(fn -> :httpc.request(:get, {url, []}, [timeout: 60_000], body_format: :binary) end)

    bytes = byte_size(body)
    if bytes != File.stat!(path).size, do: Mix.raise("the download is not the file")
    {bytes, bytes / 1_048_576 / (us / 1_000_000)}
  end

  defp wait_for(fun, tries \\ 500) do
    cond do
      fun.() -> :ok
      tries == 0 -> Mix.raise("the black box did not start")
      true -> Process.sleep(10) && wait_for(fun, tries - 1)
    end
  end

  defp pctl(sorted, p), do: Enum.at(sorted, min(length(sorted) - 1, div(length(sorted) * p, 100)))
  defp mb(bytes), do: fmt(bytes / 1_048_576, 1)
  defp fmt(x, d), do: :erlang.float_to_binary(x * 1.0, decimals: d)
end
