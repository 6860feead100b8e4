defmodule ThinkingCap.BlackBox.Recorder do
  @moduledoc """
  Records one robot's blackboard tuples into MCAP files: a process that
  subscribes to the tuples, turns each into Foxglove messages
  (`ThinkingCap.BlackBox.Foxglove`) and writes them with
  `ThinkingCap.MCAP.Writer`.

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
  begun when it holds `file_bytes` or is `file_seconds` old, and when the
  recorder stops. A chunk is written when it holds `chunk_bytes` or is
  `chunk_seconds` old: if the VM dies, the file is valid up to its last
  chunk and `ThinkingCap.MCAP.Reader` reads it so.

  ## Times

  A message's **log time is the time the recorder received the tuple**,
  in nanoseconds since the Unix epoch (`System.os_time/1`): one clock
  for every channel, in the order the tuples came. Its **publish time is
  the tuple's `stamp`** (seconds on the robot's clock: simulated time in
  a simulation) in nanoseconds, when its payload has one, else the log
  time. Foxglove messages carry the stamp in their `timestamp` too.

  ## Cost

  Per tuple: the conversion to JSON (jiffy, in C) and a record header;
  the file gets one write per chunk. The subscription drops tuples when
  the recorder falls `max_queue` (1000) behind; `info/1` counts them.
  """
  use GenServer
  require Logger

  alias ThinkingCap.BlackBox.Core.Options
  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.Blackboard
  alias ThinkingCap.Config.ADF
  alias ThinkingCap.MCAP.Writer

  @type option :: {atom(), term()}

  @typedoc "What `info/1` answers."
  @type info :: %{
          robot: atom(),
          dir: Path.t(),
          file: Path.t() | nil,
          files: [Path.t()],
          messages: non_neg_integer(),
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
  def child_spec(opts),
    do: %{
      id: {__MODULE__, opts[:robot]},
      start: {__MODULE__, :start_link, [opts]},
      restart: :transient,
      shutdown: 5_000
    }

  @doc """
  Starts a recorder (options in the moduledoc, and `name:`, a
  `GenServer` name). Raises `ArgumentError` for bad options.
  """
  @spec start_link([option()]) :: GenServer.on_start()
  def start_link(opts) do
    {name, opts} = Keyword.pop(opts, :name)

    case validate(opts) do
      {:ok, config} ->
        GenServer.start_link(__MODULE__, config, if(name, do: [name: name], else: []))

      {:error, message} ->
        raise ArgumentError, message
    end
  end

  @doc "What the recorder is doing: its files, the messages written, the tuples dropped."
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
      channels: %{},
      schemas: %{},
      sequence: %{},
      files: [],
      messages: 0,
      error: nil
    }

    with :ok <- File.mkdir_p(state.dir),
         {:ok, state} <- begin_file(state) do
      refs = for t <- templates, do: elem(Blackboard.subscribe(t), 1)
      :timer.send_interval(round(config.chunk_seconds * 1000), :tick)
      {:ok, %{state | refs: refs}}
    else
      {:error, reason} -> {:stop, {:cannot_record, state.dir, reason}}
    end
  end

  defp compression(:none), do: ""
  defp compression(algorithm), do: Atom.to_string(algorithm)

  @impl true
  def handle_info({:blackboard, _ref, tuple}, %{writer: nil} = state) when is_tuple(tuple),
    do: {:noreply, state}

  def handle_info({:blackboard, _ref, tuple}, state) when is_tuple(tuple) do
    now = System.os_time(:nanosecond)
    publish = Foxglove.stamp_ns(tuple) || now

    state =
      Enum.reduce(Foxglove.messages(tuple, now), state, fn {topic, schema, json}, state ->
        write_message(state, topic, schema, json, now, publish)
      end)

    {:noreply, maybe_rotate_by_size(state)}
  end

  def handle_info(:tick, state) do
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
    dropped = Enum.reduce(state.refs, 0, &((Blackboard.dropped(&1) || 0) + &2))

    info = %{
      robot: state.robot,
      dir: state.dir,
      file: state.path,
      files: Enum.reverse(state.files),
      messages: state.messages,
      dropped: dropped,
      error: state.error
    }

    {:reply, info, state}
  end

  def handle_call(:flush, _from, state) do
    state = close_chunk(state)
    {:reply, if(state.error, do: {:error, state.error}, else: :ok), state}
  end

  def handle_call(:rotate, _from, state) do
    closed = state.path
    state = rotate_file(state)
    {:reply, if(state.error, do: {:error, state.error}, else: {:ok, closed}), state}
  end

  @impl true
  def terminate(_reason, state), do: end_file(state)

  ## Files

  defp write_message(%{writer: nil} = state, _topic, _schema, _json, _now, _publish), do: state

  defp write_message(state, topic, schema, json, now, publish) do
    {channel, state} = channel(state, topic, schema)
    sequence = Map.get(state.sequence, channel, 0) + 1

    case Writer.add_message(state.writer, channel, now, publish, json, sequence) do
      {:ok, w} ->
        %{
          state
          | writer: w,
            sequence: Map.put(state.sequence, channel, sequence),
            messages: state.messages + 1
        }

      {:error, reason} ->
        failed(state, reason)
    end
  end

  # a topic's channel, declared (with its schema) in this file on first use
  defp channel(state, topic, schema) do
    case state.channels do
      %{^topic => id} ->
        {id, state}

      _ ->
        {schema_id, state} = schema(state, schema)
        metadata = %{"robot" => Atom.to_string(state.robot)}
        {:ok, id, w} = Writer.add_channel(state.writer, schema_id, topic, "json", metadata)
        {id, %{state | writer: w, channels: Map.put(state.channels, topic, id)}}
    end
  end

  defp schema(state, name) do
    case state.schemas do
      %{^name => id} ->
        {id, state}

      _ ->
        {:ok, id, w} = Writer.add_schema(state.writer, name, "jsonschema", Foxglove.schema(name))
        {id, %{state | writer: w, schemas: Map.put(state.schemas, name, id)}}
    end
  end

  defp close_chunk(%{writer: nil} = state), do: state

  defp close_chunk(state) do
    case Writer.close_chunk(state.writer) do
      {:ok, w} -> %{state | writer: w}
      {:error, reason} -> failed(state, reason)
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
             channels: %{},
             schemas: %{},
             sequence: %{},
             files: [path | state.files],
             error: nil
         }}

      {:error, _} = error ->
        error
    end
  end

  defp end_file(%{writer: nil} = state), do: state

  defp end_file(state) do
    case Writer.close(state.writer) do
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
end
