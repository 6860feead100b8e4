defmodule ThinkingCap.BlackBox.Recorder do
  @moduledoc """
  Records one robot's blackboard tuples into MCAP files: a process that
  subscribes to the tuples, turns each into Foxglove messages
  (`ThinkingCap.BlackBox.Foxglove`), keeps it whole too, and writes them
  with `ThinkingCap.MCAP.Writer`; and that records what the robot's
  modules received and returned, callback by callback
  (`ThinkingCap.Runtime.Trace`), so that they can be replayed
  (`ThinkingCap.Testing.Replay`, `mix tc.replay`).

      {:ok, pid} = Recorder.start_link(robot: :r1, dir: "recordings", compression: :zstd)

  Usually started through `ThinkingCap.BlackBox.record/2`, or by the ADF's
  `record:` section, or by `bin/run --record DIR`.

  ## Options

  Validated before anything starts (an unknown key or a bad value raises
  `ArgumentError` saying which and why); the same fields as the ADF's
  `record:` section (`ThinkingCap.Config.ADF`), plus:

  #{ThinkingCap.Config.Schema.describe([{:robot, {:atom, required: true, doc: "the robot whose tuples are recorded"}}])}

  ## Files

  `DIR/ROBOT_YYYYMMDDTHHMMSS.mmmZ.mcap`, named by the UTC time the file
  was begun. A file is closed (summary and footer written) and the next
  begun when it holds `file_bytes` (checked after each run of up to 32
  tuples, so a file may hold a run's more) or is `file_seconds` old, and
  when the recorder stops. A chunk is written when it holds `chunk_bytes` or is
  `chunk_seconds` old: if the VM dies, the file is valid up to its last
  chunk and `ThinkingCap.MCAP.Reader` reads it so.

  ## Channels

    * `/ID/TAG`, JSON on a Foxglove schema (`ThinkingCap.BlackBox.Foxglove`),
      for Foxglove and the MCAP tools; the large tuples that come many a
      second (the LPS, MCL's particles, the topology, the map's
      segments) at most once a second of the robot's clock (their
      stamps) each, their whole terms (below) every time;
    * `/etf/ID/TAG`, the tuple whole, in Erlang's external term format
      (`:erlang.term_to_binary/1`; message encoding `etf`, no schema): the
      exact terms the modules received, atoms, tuples and floats as they
      were (Foxglove lists these topics and does not decode them);
    * `/trace/ROBOT/NAME`, module `NAME`'s trace: its callbacks, up to
      64 in a message, `[{n, us, callback}]` (`etf` too; `n` counts the
      callbacks since the module's `init/2`, and is the message's
      sequence for its first; `us` is when the recorder got it, in µs
      after the message's log time). Modules are traced from their start when the recorder
      starts with the ADF (its `record:` section, `bin/run --record`):
      the runtime waits for it before it starts the first module
      (`ThinkingCap.Runtime.Starting`).

  With `replay: false`, only the first: Foxglove's messages, about half
  the bytes, and a recording that does not replay.

  ## Times

  A message's **log time is the time the tuple was delivered to the
  recorder**, in nanoseconds since the Unix epoch: the system's time
  when the recorder started, advanced by the monotonic clock (so that a
  change of the system's time cannot put messages out of order); one
  clock for every channel. The tuples and the callbacks come in lists
  (`ThinkingCap.Blackboard.subscribe/2`'s `batch: true`, up to 256 at a
  time or a quarter of `chunk_seconds` after the first;
  `ThinkingCap.Runtime.Trace.attach/2`'s, 64 or as long), each stamped
  when it was held for the recorder, which is its log time. Its **publish time is
  the tuple's `stamp`** (seconds on the robot's clock: simulated time in
  a simulation) in nanoseconds, when its payload has one, else the log
  time. Foxglove messages carry the stamp in their `timestamp` too.

  ## Cost

  Per tuple: its Foxglove messages' JSON and two records; per traced
  callback, a small term. The tuple's `term_to_binary/1` is made by its
  writer, in place of the copy it makes of the tuple for the recorder's
  list (`Core.Channels.held/1`, the subscription's `hold:`), and the
  recorder takes every tuple but a map as that binary, without copying
  the tuple out of the blackboard's table: the JSON of a
  `thinkingcap.Tuple`, a scan or a pose is read from it in C and
  written straight into the chunk (`ThinkingCap.MCAP.Writer.add_held/2`:
  a run's tuples in one call, their JSON never a binary or a term), and
  a large tuple (the LPS) is decoded only for
  its Foxglove message, once a second; what C leaves (a map, a term
  `Core.JSON` writes otherwise) is decoded and written in Erlang. The
  tuples and callbacks come in lists, so that the
  recorder is woken once a list rather than once a tuple. The tuples
  are written 32 at a time (or at the chunk's end): their channels found
  in Erlang, all their records made in one NIF call
  (`Core.Channels.write_held_all/3`);
  a module's callbacks go into its batch a list at a time. The writer's chunk
  stream (`ThinkingCap.MCAP.Compression.stream/1`) makes each message's
  record and index entry in C and keeps the chunk there, off the heap,
  until it closes and is compressed, on a dirty scheduler; the file gets
  one write per chunk. The process's heap stays small enough (46,422 words) that the
  VM collects it where it runs, not on a dirty scheduler. The
  subscription drops tuples when 1000
  are held for the recorder; `info/1` counts them.
  """
  use GenServer
  require Logger

  # a module's traced callbacks written in one message
  @batch 64

  # Tuples come in lists (as the modules' callbacks do, Trace's
  # batching), held a quarter of a chunk (250 ms for chunks of a second):
  # nothing of a chunk is written before its end, and the cost of a list
  # (its sending, the recorder's wake-up) is shared by more tuples. The
  # trace lists are held as long: the recorder is woken about every 4
  # tuples, not every 3 (a tenth of a chunk, 64 at most)
  @list_max 256
  @list_share 0.25

  # tuples and callbacks noted before they are written (when so many, or
  # at the chunk's tick): 512 at a time held the robots' modules up (the
  # bench's control cycles missed a fifth of their deadlines), 32 do not
  @pending_max 32

  # The tuples taken and noted, and their JSON, live in the process
  # (the open chunk does not: it is compressed as it comes). Its young
  # heap (words) stays under 131,072, the size from which the VM moves
  # a collection to a dirty scheduler: the recorder's 1 MB heap was
  # collected there, taken off its scheduler and back, at every
  # collection. Under 65,536 (512 KB) too, the heap allocator's
  # single-block threshold. 2 MB of binaries.
  @spawn_opt [min_heap_size: 46_422, min_bin_vheap_size: 262_144]

  alias ThinkingCap.BlackBox.Core.{Channels, Options}
  alias ThinkingCap.Blackboard
  alias ThinkingCap.Config.ADF
  alias ThinkingCap.MCAP.Writer
  alias ThinkingCap.Runtime.Trace

  @type option :: {atom(), term()}

  @typedoc "What `info/1` answers."
  @type info :: %{
          robot: atom(),
          dir: Path.t(),
          file: Path.t() | nil,
          files: [Path.t()],
          messages: non_neg_integer(),
          callbacks: non_neg_integer(),
          dropped: non_neg_integer(),
          error: term()
        }

  @doc """
  Checks recorder options; returns them as a map with the defaults, or a
  message naming every problem.
  """
  @spec validate([option()]) :: {:ok, map()} | {:error, String.t()}
  def validate(opts) when is_list(opts) do
    fields = [
      {:robot, {:atom, required: true, doc: "the robot"}}
      | Keyword.delete(ADF.record_fields(), :enabled)
    ]

    Options.validate(opts, :recorder, fields, "recorder options")
  end

  def validate(other), do: Options.validate(other, :recorder, [], "recorder options")

  @doc "The recorder's child spec; options as `start_link/1`."
  def child_spec(opts), do: Options.child_spec(__MODULE__, opts)

  @doc """
  Starts a recorder (options in the moduledoc, and `name:`, a
  `GenServer` name). Raises `ArgumentError` for bad options.
  """
  @spec start_link([option()]) :: GenServer.on_start()
  def start_link(opts) do
    {name, opts} = Keyword.pop(opts, :name)

    case validate(opts) do
      {:ok, config} ->
        opts = [spawn_opt: @spawn_opt] ++ if(name, do: [name: name], else: [])
        GenServer.start_link(__MODULE__, config, opts)

      {:error, message} ->
        raise ArgumentError, message
    end
  end

  @doc """
  What the recorder is doing: its files, the messages written (`callbacks`
  of them the modules' traced callbacks), the tuples dropped.
  """
  @spec info(GenServer.server()) :: info()
  def info(server), do: GenServer.call(server, :info)

  @doc "Writes the open chunk now (the file stays open)."
  @spec flush(GenServer.server()) :: :ok | {:error, term()}
  def flush(server), do: GenServer.call(server, :flush)

  @doc "Closes the current file and begins the next; returns the closed file's path."
  @spec rotate(GenServer.server()) :: {:ok, Path.t() | nil} | {:error, term()}
  def rotate(server), do: GenServer.call(server, :rotate)

  ## Server

  @impl true
  def init(config) do
    Process.flag(:trap_exit, true)
    templates = if config.templates == [], do: [{:_, config.robot, :_}], else: config.templates

    state = %{
      robot: config.robot,
      dir: Path.expand(config.dir),
      compression: compression(config.compression),
      chunk_bytes: config.chunk_bytes,
      file_bytes: config.file_bytes,
      file_ms: round(config.file_seconds * 1000),
      refs: [],
      writer: nil,
      path: nil,
      started: nil,
      epoch: System.os_time(:nanosecond) - System.monotonic_time(:nanosecond),
      native_ns?: System.convert_time_unit(1, :second, :native) == 1_000_000_000,
      replay: config.replay,
      batches: %{},
      # noted, not yet written: [{:tuple, time, tuple} | {:callback, time, name, n, event}],
      # newest first (callbacks that come in lists go straight to `batches`)
      pending: [],
      pending_n: 0,
      chans: Channels.new(config.robot, terms: config.replay),
      files: [],
      messages: 0,
      callbacks: 0,
      error: nil
    }

    with :ok <- File.mkdir_p(state.dir),
         {:ok, state} <- begin_file(state) do
      lists = [batch: true, max_batch: @list_max, max_delay_ms: list_ms(config.chunk_seconds)]
      # the tuples' terms made by their writers (Channels.held/1)
      lists = if config.replay, do: [{:hold, {Channels, :held}} | lists], else: lists
      refs = for t <- templates, do: elem(Blackboard.subscribe(t, lists), 1)
      trace = [batch: true, max_delay_ms: lists[:max_delay_ms]]
      if config.replay, do: :ok = Trace.attach(config.robot, trace)
      :timer.send_interval(round(config.chunk_seconds * 1000), :tick)
      {:ok, %{state | refs: refs}}
    else
      {:error, reason} -> {:stop, {:cannot_record, state.dir, reason}}
    end
  end

  defp list_ms(chunk_seconds), do: max(round(chunk_seconds * 1000 * @list_share), 1)

  defp compression(:none), do: ""
  defp compression(algorithm), do: Atom.to_string(algorithm)

  # A tuple or a traced callback is noted with its log time and written
  # with the others noted when `@pending_max` are, or at the chunk's
  # tick: encoding one or two at a time, its code and data cold again,
  # costs more CPU than in a batch. A chunk is only written at its end,
  # so a VM killed loses no more than before.
  @impl true
  def handle_info({:blackboard_held, ref}, state) when is_reference(ref),
    do: {:noreply, state |> take_held(ref) |> drained()}

  # a module's callbacks (ThinkingCap.Runtime.Trace), in a list
  def handle_info({:tc_trace_batch, robot, name, events}, %{robot: robot} = state)
      when is_list(events),
      do: {:noreply, add_callbacks(state, name, events)}

  # one at a time: a subscription or a trace not in lists
  def handle_info({:blackboard, _ref, tuple}, state) when is_tuple(tuple),
    do: {:noreply, note(state, {:tuple, now(state), tuple})}

  def handle_info({:tc_trace, robot, name, n, event}, %{robot: robot} = state),
    do: {:noreply, note(state, {:callback, now(state), name, n, event})}

  def handle_info(:tick, state) do
    state = drain(state)

    state =
      cond do
        state.writer == nil -> retry(state)
        now_ms() - state.started >= state.file_ms -> rotate_file(state)
        true -> close_chunk(state)
      end

    {:noreply, state}
  end

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def handle_call(:info, _from, state) do
    state = state |> collect() |> drain()
    dropped = Enum.reduce(state.refs, 0, &((Blackboard.dropped(&1) || 0) + &2))

    info = %{
      robot: state.robot,
      dir: state.dir,
      file: state.path,
      files: Enum.reverse(state.files),
      messages: state.messages,
      callbacks: state.callbacks,
      dropped: dropped,
      error: state.error
    }

    {:reply, info, state}
  end

  def handle_call(:flush, _from, state) do
    state = state |> collect() |> drain() |> close_chunk()
    {:reply, if(state.error, do: {:error, state.error}, else: :ok), state}
  end

  def handle_call(:rotate, _from, state) do
    state = state |> collect() |> drain()
    closed = state.path
    state = rotate_file(state)
    {:reply, if(state.error, do: {:error, state.error}, else: {:ok, closed}), state}
  end

  @impl true
  def terminate(_reason, state), do: state |> collect() |> drain() |> end_file()

  # The tuples held for the recorder and the lists of callbacks in its
  # mailbox, noted: so that a flush, a rotation or a stop leaves nothing
  # delivered unwritten.
  defp collect(state) do
    state = Enum.reduce(state.refs, state, &take_held(&2, &1))
    take_lists(state)
  end

  defp take_held(state, ref) do
    entries = Blackboard.take_held(ref)
    add_all(state, entries, fn {tuple, at}, s -> {:tuple, log_time(s, at), tuple} end)
  end

  defp take_lists(%{robot: robot} = state) do
    receive do
      # a notice is taken (its flag cleared), so that the next one comes
      {:blackboard_held, ref} when is_reference(ref) ->
        state |> take_held(ref) |> take_lists()

      {:tc_trace_batch, ^robot, name, events} when is_list(events) ->
        state |> add_callbacks(name, events) |> take_lists()
    after
      0 -> state
    end
  end

  # noted newest first, the state updated once
  defp add_all(state, items, item) do
    {pending, n} = note_all(items, item, state, state.pending, state.pending_n)
    %{state | pending: pending, pending_n: n}
  end

  defp note_all([], _item, _state, pending, n), do: {pending, n}

  defp note_all([x | rest], item, state, pending, n),
    do: note_all(rest, item, state, [item.(x, state) | pending], n + 1)

  ## Noted messages

  defp note(state, item), do: state |> add(item) |> drained()

  defp add(state, item),
    do: %{state | pending: [item | state.pending], pending_n: state.pending_n + 1}

  defp drained(state), do: if(state.pending_n >= @pending_max, do: drain(state), else: state)

  defp drain(%{pending: []} = state), do: state

  defp drain(state) do
    items = Enum.reverse(state.pending)
    state = %{state | pending: [], pending_n: 0}
    state = write_items(items, [], 0, state)
    maybe_rotate_by_size(state)
  end

  # in order: each run of tuples (`@pending_max` at most: a file is
  # closed past `file_bytes` after a run) written in one call, their
  # records made in one NIF call; each callback as it comes
  defp write_items([{:tuple, now, tuple} | rest], run, n, state) when n < @pending_max,
    do: write_items(rest, [{tuple, now} | run], n + 1, state)

  defp write_items(rest, [_ | _] = run, _n, state),
    do: write_items(rest, [], 0, write_tuples(:lists.reverse(run), state))

  defp write_items([item | rest], [], 0, state),
    do: write_items(rest, [], 0, write_item(item, state))

  defp write_items([], [], 0, state), do: state

  # no file (a write failed): dropped until one is begun again
  defp write_tuples(_entries, %{writer: nil} = state), do: state

  defp write_tuples(entries, state) do
    case Channels.write_held_all(state.writer, state.chans, entries) do
      {:ok, w, chans, n} ->
        maybe_rotate_by_size(%{state | writer: w, chans: chans, messages: state.messages + n})

      {:error, reason, chans} ->
        failed(%{state | chans: chans}, reason)
    end
  end

  defp write_item(_item, %{writer: nil} = state), do: state

  # kept a moment, and written `@batch` at a time (or at the chunk's
  # end): one message per callback would cost more in record headers
  # and indexes than the callbacks themselves
  defp write_item({:callback, now, name, n, event}, state) do
    {time, events, count} = Map.get(state.batches, name, {now, [], 0})
    # each with its own receipt time, in µs after the message's log time
    batches =
      Map.put(
        state.batches,
        name,
        {time, [{n, div(now - time, 1000), event} | events], count + 1}
      )

    state = %{state | batches: batches, callbacks: state.callbacks + 1}
    if count + 1 >= @batch, do: maybe_rotate_by_size(write_batch(state, name)), else: state
  end

  # A module's list of callbacks, `[{n, at, event}]`, straight into its
  # batch (as `write_item/2` adds one), the state updated once a list
  # rather than once a callback; a batch is written when it holds `@batch`.
  defp add_callbacks(%{writer: nil} = state, _name, _events), do: state

  defp add_callbacks(state, name, events) do
    {time, acc, count} = Map.get(state.batches, name, {nil, [], 0})
    add_callbacks(state, name, events, time, acc, count, 0)
  end

  defp add_callbacks(state, _name, [], _time, _acc, 0, k),
    do: %{state | callbacks: state.callbacks + k}

  defp add_callbacks(state, name, [], time, acc, count, k),
    do: %{
      state
      | batches: Map.put(state.batches, name, {time, acc, count}),
        callbacks: state.callbacks + k
    }

  defp add_callbacks(state, name, [{n, at, event} | rest], time, acc, count, k) do
    now = log_time(state, at)
    # the batch's time is its first callback's; each one's in µs after it
    time = time || now
    acc = [{n, div(now - time, 1000), event} | acc]

    if count + 1 >= @batch do
      batches = Map.put(state.batches, name, {time, acc, count + 1})
      state = %{state | batches: batches, callbacks: state.callbacks + k + 1}
      state |> write_batch(name) |> maybe_rotate_by_size() |> add_callbacks(name, rest)
    else
      add_callbacks(state, name, rest, time, acc, count + 1, k + 1)
    end
  end

  ## Files

  defp close_chunk(%{writer: nil} = state), do: state

  defp close_chunk(state) do
    state = write_batches(state)

    case state.writer && Writer.close_chunk(state.writer) do
      nil -> state
      {:ok, w} -> %{state | writer: w}
      {:error, reason} -> failed(state, reason)
    end
  end

  defp write_batches(state),
    do: state.batches |> Map.keys() |> Enum.reduce(state, &write_batch(&2, &1))

  defp write_batch(%{writer: nil} = state, _name), do: %{state | batches: %{}}

  defp write_batch(state, name) do
    {{time, events, _count}, batches} = Map.pop(state.batches, name)
    state = %{state | batches: batches}

    case Channels.write_trace(state.writer, state.chans, name, Enum.reverse(events), time) do
      {:ok, w, chans} -> %{state | writer: w, chans: chans, messages: state.messages + 1}
      {:error, reason, chans} -> failed(%{state | chans: chans}, reason)
    end
  end

  defp maybe_rotate_by_size(%{writer: nil} = state), do: state

  defp maybe_rotate_by_size(state) do
    if Writer.bytes_written(state.writer) >= state.file_bytes,
      do: rotate_file(state),
      else: state
  end

  defp rotate_file(state) do
    state = end_file(state)

    case begin_file(state) do
      {:ok, state} -> state
      {:error, reason} -> failed(state, reason)
    end
  end

  defp begin_file(state) do
    path = file_path(state.dir, state.robot)

    case Writer.open(path, compression: state.compression, chunk_bytes: state.chunk_bytes) do
      {:ok, w} ->
        {:ok,
         %{
           state
           | writer: w,
             path: path,
             started: now_ms(),
             chans: Channels.new(state.robot, terms: state.replay),
             files: [path | state.files],
             error: nil
         }}

      {:error, _} = error ->
        error
    end
  end

  defp end_file(%{writer: nil} = state), do: state

  defp end_file(state) do
    state = write_batches(state)

    case state.writer && Writer.close(state.writer) do
      nil -> state
      {:ok, _bytes} -> %{state | writer: nil, path: nil}
      {:error, reason} -> failed(state, reason)
    end
  end

  # a write failed (the disk full, the directory gone): the file is left
  # valid up to its last chunk; a new one is tried every tick
  defp failed(state, reason) do
    if state.writer, do: Writer.abandon(state.writer)

    if state.error == nil,
      do: Logger.error("recorder for #{inspect(state.robot)}: #{inspect(reason)}; retrying")

    %{state | writer: nil, path: nil, error: reason}
  end

  defp retry(state) do
    case begin_file(state) do
      {:ok, state} -> state
      {:error, reason} -> %{state | error: reason}
    end
  end

  defp file_path(dir, robot) do
    stamp =
      DateTime.utc_now()
      |> DateTime.truncate(:millisecond)
      |> Calendar.strftime("%Y%m%dT%H%M%S.%fZ")

    base = Path.join(dir, "#{safe(robot)}_#{stamp}")
    unique(base, 0)
  end

  defp unique(base, n) do
    path = if n == 0, do: base <> ".mcap", else: "#{base}-#{n}.mcap"
    if File.exists?(path), do: unique(base, n + 1), else: path
  end

  defp safe(robot), do: robot |> Atom.to_string() |> String.replace(~r/[^A-Za-z0-9_-]/, "_")

  defp now_ms, do: System.monotonic_time(:millisecond)

  # the log time: the epoch's, on the monotonic clock
  defp now(state), do: state.epoch + System.monotonic_time(:nanosecond)

  # the log time of a tuple or callback held for a list: when it was held
  # (the native unit is the nanosecond on Linux: nothing to convert)
  defp log_time(%{native_ns?: true, epoch: epoch}, at), do: epoch + at
  defp log_time(state, at), do: state.epoch + System.convert_time_unit(at, :native, :nanosecond)
end
