defmodule ThinkingCap.BlackBox.ReplayRecordingTest do
  # Recordings written here, as the recorder writes them, each missing
  # what a replay needs in its own way; and terms from outside.
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Core.{Channels, Terms}
  alias ThinkingCap.BlackBox.Replay
  alias ThinkingCap.MCAP.Writer
  alias ThinkingCap.Runtime.Trace

  @moduletag :tmp_dir

  defmodule Summer do
    @moduledoc false
    # sums the ticks it is sent; a tick of :boom raises
    use ThinkingCap.Module

    @impl true
    def init(_params, ctx), do: {[subscribe: {:tick, ctx.robot, :_}], %{robot: ctx.robot, sum: 0}}

    @impl true
    def handle_tuple({:tick, _robot, %{n: :boom}}, _state), do: raise("boom")

    def handle_tuple({:tick, robot, %{n: n}}, state) do
      sum = state.sum + n
      {[out: {{:sum, robot, %{sum: sum}}, [key: {:sum, robot}]}], %{state | sum: sum}}
    end
  end

  @robot :summing_robot

  # what the robot's recorder would hold: each tick and each sum whole,
  # and the module's trace as its host sends it
  defp recording(ns) do
    init =
      {:init,
       %{
         module: Summer,
         params: [],
         context: %{robot: @robot, name: :summer, node: node(), activity: :event},
         activity: :event,
         period: nil,
         node: node()
       }}

    {items, _sum} =
      Enum.map_reduce(ns, 0, fn n, sum ->
        tick = {:tick, @robot, %{n: n}}

        case n do
          :boom ->
            {%{tick: tick, out: nil, event: {{:tuple, Trace.ref(tick, @robot)}, raised()}}, sum}

          n ->
            out = {:sum, @robot, %{sum: sum + n}}
            outputs = [{:out, Trace.ref(out, @robot), [key: {:sum, @robot}]}]

            {%{tick: tick, out: out, event: {{:tuple, Trace.ref(tick, @robot)}, outputs}},
             sum + n}
        end
      end)

    %{
      init: {init, [{:subscribe, {:tick, @robot, :_}}]},
      items: items
    }
  end

  defp raised, do: {:raised, :error, "** (RuntimeError) boom"}

  # writes it, leaving out what `drop` says: tuples or traced callbacks
  defp write(dir, rec, drop \\ fn _ -> false end) do
    path = Path.join(dir, "rec#{System.unique_integer([:positive])}.mcap")
    {:ok, w} = Writer.open(path, compression: "")
    chans = Channels.new(@robot)
    t0 = 1_000_000_000_000
    {w, chans} = trace(w, chans, 0, rec.init, t0, drop)

    {w, _chans} =
      rec.items
      |> Enum.with_index(1)
      |> Enum.reduce({w, chans}, fn {item, n}, {w, chans} ->
        t = t0 + n * 10_000_000
        {w, chans} = tuple(w, chans, item.tick, t, drop)
        {w, chans} = if item.out, do: tuple(w, chans, item.out, t + 1, drop), else: {w, chans}
        trace(w, chans, n, item.event, t + 2, drop)
      end)

    {:ok, _} = Writer.close(w)
    path
  end

  defp tuple(w, chans, tuple, t, drop) do
    if drop.({:tuple, tuple}) do
      {w, chans}
    else
      {:ok, w, chans, _} = Channels.write_tuple(w, chans, tuple, t)
      {w, chans}
    end
  end

  defp trace(w, chans, n, event, t, drop) do
    if drop.({:trace, n}) do
      {w, chans}
    else
      {:ok, w, chans} = Channels.write_trace(w, chans, :summer, [{n, 0, event}], t)
      {w, chans}
    end
  end

  defp compare(path) do
    {:ok, rec} = Replay.open(path)
    {:ok, %{summer: report}} = Replay.compare(rec, :summer)
    report
  end

  test "a module replays from its recorded trace, its raise included", %{tmp_dir: dir} do
    path = write(dir, recording([1, 2, :boom, 3]))
    {:ok, rec} = Replay.open(path)
    assert Replay.robot(rec) == @robot

    assert [%{name: :summer, module: Summer, activity: :event, callbacks: 5, from_start: true}] =
             Replay.modules(rec)

    {:ok, %{summer: report}} = Replay.compare(rec, :summer)
    assert report.identical
    # init's subscription, three sums, the raise
    assert report.outputs == 5 and report.equal == 5 and report.callbacks == 5
  end

  test "an output recorded otherwise is a difference, shown whole", %{tmp_dir: dir} do
    rec = recording([1, 2, 3])
    wrong = {:sum, @robot, %{sum: 99}}

    rec =
      update_in(rec.items, fn [a, b, c] ->
        [
          a,
          %{b | out: wrong, event: put_elem(b.event, 1, [{:out, Trace.ref(wrong, @robot), []}])},
          c
        ]
      end)

    report = compare(write(dir, rec))
    refute report.identical
    assert report.differences == 1 and report.equal == report.outputs - 1

    assert [%{callback: 2, input: {:tuple, :tick}, recorded: recorded, replayed: replayed}] =
             report.first_differences

    assert recorded == {:out, wrong, []}
    assert replayed == {:out, {:sum, @robot, %{sum: 3}}, [key: {:sum, @robot}]}
  end

  test "a recording begun after the module started cannot replay it", %{tmp_dir: dir} do
    report = compare(write(dir, recording([1, 2, 3]), &(&1 == {:trace, 0})))
    refute report.identical
    assert report.callbacks == 0
    assert report.stopped =~ "the recording began after :summer started"
  end

  test "callbacks missing from the recording stop the replay there", %{tmp_dir: dir} do
    report = compare(write(dir, recording([1, 2, 3, 4]), &(&1 == {:trace, 2})))
    assert report.callbacks == 2
    assert report.stopped == "callbacks 2 to 2 of :summer are not in the recording"
  end

  test "an input tuple the recorder did not keep stops the replay there", %{tmp_dir: dir} do
    lost = {:tick, @robot, %{n: 3}}
    report = compare(write(dir, recording([1, 2, 3, 4]), &(&1 == {:tuple, lost})))
    assert report.callbacks == 3

    assert report.stopped ==
             "a :tick tuple :summer received (callback 3) is not in the recording " <>
               "(the recorder dropped it, or its templates left it out)"
  end

  test "only a ThinkingCap.Module's code is run, whatever a recording names", %{tmp_dir: dir} do
    rec = recording([1, 2])
    {{:init, info}, outputs} = rec.init
    rec = %{rec | init: {{:init, %{info | module: File}}, outputs}}
    report = compare(write(dir, rec))
    assert report.callbacks == 0

    assert report.stopped ==
             "File is not a ThinkingCap.Module here (not loaded, or not one): " <>
               ":summer cannot be run again"
  end

  test "a trace that is not one is refused when the recording is opened", %{tmp_dir: dir} do
    path = Path.join(dir, "bogus.mcap")
    {:ok, w} = Writer.open(path, compression: "")
    chans = Channels.new(@robot)
    {:ok, w, chans, _} = Channels.write_tuple(w, chans, {:tick, @robot, %{n: 1}}, 1)

    {:ok, w, _chans} =
      Channels.write_trace(w, chans, :summer, [{0, 0, {{:init, :nothing}, []}}], 2)

    {:ok, _} = Writer.close(w)
    assert {:error, message} = Replay.open(path)

    assert message =~
             "/trace/summing_robot/summer (sequence 0): not a list of traced callbacks: [{0, 0,"
  end

  test "what cannot be replayed is refused, saying why", %{tmp_dir: dir} do
    text = Path.join(dir, "notes.mcap")
    File.write!(text, "not an MCAP file")
    assert {:error, message} = Replay.open(text)
    assert message =~ "notes.mcap: not a readable MCAP file"

    assert {:error, message} = Replay.open(Path.join(dir, "missing.mcap"))
    assert message =~ "missing.mcap: no such file"

    # a recording from before the whole terms: Foxglove's messages only
    old = Path.join(dir, "old.mcap")
    {:ok, w} = Writer.open(old, compression: "")
    {:ok, schema, w} = Writer.add_schema(w, "thinkingcap.Tuple", "jsonschema", "{}")
    {:ok, ch, w} = Writer.add_channel(w, schema, "/r1/drive", "json", %{"robot" => "r1"})
    {:ok, w} = Writer.add_message(w, ch, 1, 1, ~s({"tag":"drive"}))
    {:ok, _} = Writer.close(w)
    assert {:error, message} = Replay.open(old)
    assert message =~ "old.mcap: no whole terms (no /etf/ channels)"

    # two robots' files: one must be chosen
    a = write(dir, recording([1]))
    assert {:error, message} = Replay.open([a, old])
    assert message =~ "the files hold several robots (r1, summing_robot): choose one (--robot)"
    assert {:ok, _} = Replay.open([a, old], robot: @robot)
    assert {:error, message} = Replay.open(a, robot: :r7)
    assert message =~ "no recording of robot r7"
  end

  test "terms from outside make atoms only within a budget" do
    name = "tc_replay_never_seen_#{System.unique_integer([:positive])}"
    # {:tick, <an atom this VM does not know>, [1.5]}, written by hand
    bin =
      <<131, 104, 3, 119, 4, "tick", 119, byte_size(name), name::binary, 108, 0, 0, 0, 1, 70,
        1.5::float, 106>>

    assert_raise ArgumentError, fn -> :erlang.binary_to_term(bin, [:safe]) end
    assert {:error, message} = Terms.decode(bin, 0)
    assert message =~ "more atoms unknown to this VM than a recording may"
    assert {:ok, {:tick, atom, [1.5]}, 9} = Terms.decode(bin, 10)
    assert Atom.to_string(atom) == name

    assert {:ok, [_ | _]} = Terms.atoms(:erlang.term_to_binary({self(), make_ref(), %{a: "b"}}))
    assert {:error, _} = Terms.decode(<<131, 255, 0>>, 10)
    assert {:error, _} = Terms.decode("plain text", 10)
    # funs are refused, whatever atoms they name
    assert {:error, _} = Terms.atoms(:erlang.term_to_binary(fn -> :ok end))
  end
end
