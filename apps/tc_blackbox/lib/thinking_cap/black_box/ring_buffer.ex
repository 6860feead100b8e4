defmodule ThinkingCap.BlackBox.RingBuffer do
  @moduledoc """
  The black box of one robot: the last `seconds` of its tuples, kept in
  memory, dumped to an MCAP file on an incident without anyone asking.

      {:ok, pid} = RingBuffer.start_link(robot: :r1, dir: "black_box", seconds: 60, after: 5)

  Usually started by `ThinkingCap.BlackBox.keep/2` or by the ADF's
  `black_box:` section (on by default where this app runs).

  ## What it keeps

  Every tuple of the robot (`{:_, robot, :_}`) and the `:timing`
  summaries of its periodic modules (`activities:`), each as it came,
  with its receipt time: nothing is converted until a dump. The oldest
  go first past `seconds` (kept longer while a dump waits for them),
  past `max_bytes` (the tuples' external size) and past `max_messages`;
  those dropped for size or count are counted in `info/1`.

  ## Triggers

  | incident | tuple | reason |
  |---|---|---|
  | an E-stop engaged | `{:estop, robot, %{engaged: true}}` (not engaged before) | `estop` |
  | a bumper contact | a reading `%{pressed: true}` (not pressed before), any sensor | `bumper` |
  | a layer that gave up | `{:module_gave_up, robot, _}` | `module_gave_up` |
  | deadline misses | `{:timing, activity, %{fallbacks: n}}` of one of its modules: `misses` in a streak of summaries each with a new miss | `deadline_misses` |
  | localization lost | `{:pose, robot, %{status: :lost}}` (not lost before) | `localization_lost` |
  | a request | `{:black_box_request, robot, %{reason: r}}`, `ThinkingCap.BlackBox.dump/3` | `r` |

  A module's single crash is not on the blackboard (the supervision
  warden only remembers it): only a give-up triggers.

  ## Dumps

  A dump covers `seconds` before its trigger and `after` seconds after
  it. A trigger that comes while a dump waits to be written joins it:
  the dump goes on `after` seconds past the last one (at most `seconds`
  past the first) and lists every reason. The file is
  `DIR/ROBOT_YYYYMMDDTHHMMSS.mmmZ_REASON.mcap` (the UTC time of the
  first trigger), with the recorder's channels and schemas
  (`ThinkingCap.BlackBox.Recorder`), written by a task so the buffer
  goes on receiving. Each dump is announced as
  `{:black_box_dump, robot, %{path:, reason:, reasons:, from:, to:,
  messages:, node:}}` (times in ms since the epoch).

  ## Options

  #{ThinkingCap.Config.Schema.describe([{:robot, {:atom, required: true, doc: "the robot"}}, {:activities, {{:list, :atom}, default: [], doc: "the robot's periodic activities (its modules' names), whose deadline misses count"}}])}
  and the ADF's `black_box:` keys but `enabled` (`ThinkingCap.Config.ADF`).
  """
  use GenServer

  # the incidents kept for the timeline
  @max_incidents 100
  require Logger

  alias ThinkingCap.BlackBox.Core.{DumpFile, Options, Ring, Triggers}
  alias ThinkingCap.Blackboard
  alias ThinkingCap.Config.ADF
  alias ThinkingCap.Tuples
  require Tuples

  @typedoc "What `info/1` answers."
  @type info :: %{
          robot: atom(),
          dir: Path.t(),
          messages: non_neg_integer(),
          bytes: non_neg_integer(),
          dropped: non_neg_integer(),
          pending: map() | nil,
          dumps: non_neg_integer()
        }

  @doc "Checks the options; returns them as a map with the defaults, or the problems."
  @spec validate(keyword()) :: {:ok, map()} | {:error, String.t()}
  def validate(opts) when is_list(opts) do
    fields = [
      {:robot, {:atom, required: true, doc: "the robot"}},
      {:activities, {{:list, :atom}, default: [], doc: "its periodic activities"}}
      | Keyword.delete(ADF.black_box_fields(), :enabled)
    ]

    Options.validate(opts, :black_box, fields, "black-box options")
  end

  def validate(other), do: Options.validate(other, :black_box, [], "black-box options")

  @doc "The child spec; options as `start_link/1`."
  def child_spec(opts), do: Options.child_spec(__MODULE__, opts)

  @doc "Starts a ring buffer (options above, and `name:`). Raises `ArgumentError` for bad options."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts) do
    {name, opts} = Keyword.pop(opts, :name)

    case validate(opts) do
      {:ok, config} ->
        GenServer.start_link(__MODULE__, config, if(name, do: [name: name], else: []))

      {:error, message} ->
        raise ArgumentError, message
    end
  end

  @doc """
  Dumps now, for `reason`, and answers the file's path once it is
  written (`after` seconds later, or more if other triggers join).
  """
  @spec dump(GenServer.server(), term(), timeout()) :: {:ok, Path.t()} | {:error, term()}
  def dump(server, reason, timeout \\ 120_000),
    do: GenServer.call(server, {:dump, Triggers.text(reason)}, timeout)

  @typedoc """
  What `snapshot/3` answers: the tuples held (those of the tags asked
  for), oldest first, each with its receipt time, and the span they
  cover, `from` (the oldest tuple held, of any tag) to `to` (the
  moment of the snapshot); times in ns since the epoch. `incidents`
  are the triggers of the span (and the dump requests), oldest first,
  at most #{@max_incidents}: when and why. `dropped`
  counts the tuples dropped for size or count since the start.
  """
  @type snapshot :: %{
          robot: atom(),
          from: integer(),
          to: integer(),
          entries: [{integer(), tuple()}],
          incidents: [%{at: integer(), reason: String.t()}],
          dropped: non_neg_integer()
        }

  @doc """
  A copy of what it holds now, for replay (the dashboard's timeline):
  the tuples whose tag is in `tags` (`:all`: every one). The buffer goes
  on; the copy does not move.
  """
  @spec snapshot(GenServer.server(), [atom()] | :all, timeout()) :: snapshot()
  def snapshot(server, tags \\ :all, timeout \\ 30_000)
      when tags == :all or is_list(tags),
      do: GenServer.call(server, {:snapshot, tags}, timeout)

  @doc "What it holds: tuples, bytes, drops (size or count), the dump waiting, the dumps written."
  @spec info(GenServer.server()) :: info()
  def info(server), do: GenServer.call(server, :info)

  ## Server

  @impl true
  def init(config) do
    {:ok, _} = Blackboard.subscribe({:_, config.robot, :_})
    if config.activities != [], do: {:ok, _} = Blackboard.subscribe(Tuples.timing())

    {:ok,
     %{
       robot: config.robot,
       dir: Path.expand(config.dir),
       keep_ns: round(config.seconds * 1.0e9),
       after_ns: round(config.after * 1.0e9),
       compression: if(config.compression == :none, do: "", else: "#{config.compression}"),
       ring: Ring.new(config.max_bytes, config.max_messages),
       triggers: Triggers.new(config.robot, config.activities, config.misses),
       incidents: [],
       pending: nil,
       writing: %{},
       dumps: 0
     }}
  end

  @impl true
  def handle_info({:blackboard, _ref, tuple}, state) when is_tuple(tuple) do
    now = System.os_time(:nanosecond)
    state = %{state | ring: Ring.push(state.ring, now, tuple)}
    {reason, triggers} = Triggers.check(state.triggers, tuple)
    state = %{state | triggers: triggers}
    state = if reason, do: trigger(state, reason, now, nil), else: state
    {:noreply, age(state, now)}
  end

  def handle_info(:write, state), do: {:noreply, maybe_write(state)}

  # a dump's task finished
  def handle_info({ref, result}, state)
      when is_reference(ref) and is_map_key(state.writing, ref) do
    Process.demonitor(ref, [:flush])
    {{dump, froms}, writing} = Map.pop(state.writing, ref)
    state = %{state | writing: writing}

    case result do
      {:ok, messages} ->
        announce(state.robot, dump, messages)
        for f <- froms, do: GenServer.reply(f, {:ok, dump.path})
        {:noreply, %{state | dumps: state.dumps + 1}}

      {:error, reason} ->
        Logger.error("black box of #{inspect(state.robot)}: #{dump.path}: #{inspect(reason)}")
        for f <- froms, do: GenServer.reply(f, {:error, reason})
        {:noreply, state}
    end
  end

  def handle_info({:DOWN, ref, :process, _, reason}, state) when is_map_key(state.writing, ref) do
    {{dump, froms}, writing} = Map.pop(state.writing, ref)
    Logger.error("black box of #{inspect(state.robot)}: #{dump.path}: #{inspect(reason)}")
    for f <- froms, do: GenServer.reply(f, {:error, reason})
    {:noreply, %{state | writing: writing}}
  end

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def handle_call({:dump, reason}, from, state) do
    {:noreply, state |> trigger(reason, System.os_time(:nanosecond), from) |> maybe_write()}
  end

  def handle_call({:snapshot, tags}, _from, state) do
    now = System.os_time(:nanosecond)

    snapshot = %{
      robot: state.robot,
      from: Ring.oldest(state.ring) || now,
      to: now,
      entries: Ring.select(state.ring, tags),
      incidents: for({t, reason} <- Enum.reverse(state.incidents), do: %{at: t, reason: reason}),
      dropped: state.ring.dropped
    }

    {:reply, snapshot, state}
  end

  def handle_call(:info, _from, state) do
    info = %{
      robot: state.robot,
      dir: state.dir,
      messages: state.ring.count,
      bytes: state.ring.bytes,
      dropped: state.ring.dropped,
      pending: state.pending && Map.take(state.pending, [:reasons, :from, :to]),
      dumps: state.dumps
    }

    {:reply, info, state}
  end

  ## Dumps

  # a trigger at `t`: remembered as an incident (the timeline marks it),
  # and a new dump, or the one waiting goes on
  defp trigger(state, reason, t, from) do
    incidents = Enum.take([{t, reason} | state.incidents], @max_incidents)
    pend(%{state | incidents: incidents}, reason, t, from)
  end

  defp pend(%{pending: nil} = state, reason, t, from) do
    Logger.info("black box of #{inspect(state.robot)}: #{reason}; dumping")

    pending = %{
      reasons: [reason],
      at: t,
      from: t - state.keep_ns,
      to: t + state.after_ns,
      froms: List.wrap(from)
    }

    schedule(%{state | pending: pending})
  end

  defp pend(%{pending: p} = state, reason, t, from) do
    to = min(max(p.to, t + state.after_ns), p.at + state.keep_ns)
    reasons = if reason in p.reasons, do: p.reasons, else: p.reasons ++ [reason]

    schedule(%{
      state
      | pending: %{p | to: to, reasons: reasons, froms: List.wrap(from) ++ p.froms}
    })
  end

  defp schedule(%{pending: %{to: to}} = state) do
    ms = max(0, div(to - System.os_time(:nanosecond), 1_000_000) + 1)
    Process.send_after(self(), :write, ms)
    state
  end

  defp maybe_write(%{pending: nil} = state), do: state

  defp maybe_write(%{pending: p} = state) do
    if System.os_time(:nanosecond) >= p.to, do: write(state), else: state
  end

  defp write(%{pending: p} = state) do
    entries = Ring.slice(state.ring, p.from, p.to)
    path = path(state.dir, state.robot, p.at, hd(p.reasons))
    dump = %{path: path, reasons: p.reasons, from: p.from, to: p.to}
    {robot, compression} = {state.robot, state.compression}

    task =
      Task.Supervisor.async_nolink(ThinkingCap.BlackBox.DumpWriters, fn ->
        DumpFile.write(path, robot, entries, compression)
      end)

    %{state | pending: nil, writing: Map.put(state.writing, task.ref, {dump, p.froms})}
  end

  defp announce(robot, dump, messages) do
    payload = %{
      path: dump.path,
      reason: hd(dump.reasons),
      reasons: dump.reasons,
      from: div(dump.from, 1_000_000),
      to: div(dump.to, 1_000_000),
      messages: messages,
      node: node()
    }

    {tuple, opts} = Tuples.keyed(Tuples.black_box_dump(robot, payload))
    Blackboard.out(tuple, opts)
  end

  # what is older than `seconds` goes, unless a dump waits for it
  defp age(state, now) do
    keep_from = now - state.keep_ns
    keep_from = if state.pending, do: min(keep_from, state.pending.from), else: keep_from
    incidents = Enum.take_while(state.incidents, fn {t, _} -> t >= now - state.keep_ns end)
    %{state | ring: Ring.forget_before(state.ring, keep_from), incidents: incidents}
  end

  @doc false
  # DIR/ROBOT_YYYYMMDDTHHMMSS.mmmZ_REASON.mcap, unique
  def path(dir, robot, t_ns, reason) do
    stamp =
      t_ns
      |> div(1_000_000)
      |> DateTime.from_unix!(:millisecond)
      |> Calendar.strftime("%Y%m%dT%H%M%S.%fZ")

    base = Path.join(dir, "#{safe(robot)}_#{stamp}_#{safe(reason)}")
    unique(base, 0)
  end

  defp unique(base, n) do
    path = if n == 0, do: base <> ".mcap", else: "#{base}-#{n}.mcap"
    if File.exists?(path), do: unique(base, n + 1), else: path
  end

  defp safe(name),
    do: name |> to_string() |> String.replace(~r/[^A-Za-z0-9_-]/, "_") |> String.slice(0, 60)
end
