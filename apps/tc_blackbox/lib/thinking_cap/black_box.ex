defmodule ThinkingCap.BlackBox do
  @moduledoc """
  The black box: recording robots' blackboard tuples into MCAP files
  (`ThinkingCap.MCAP`) that open in Foxglove and the MCAP tools.

  One recorder (`ThinkingCap.BlackBox.Recorder`) per robot, supervised by
  this app. Three ways to start one:

    * `record/2` here: `ThinkingCap.BlackBox.record(:r1, dir: "recordings")`;
    * an ADF's `record:` section (`record: [enabled: true, dir: "recordings"]`,
      keys in `ThinkingCap.Config.ADF`): the runtime checks it when it
      reads the file, and this app's launcher starts the recorder when
      the runtime announces the ADF started on this node. The runtime
      does not depend on this app (it is below it): the announcement,
      `{:adf, robot, %{record: ...}}` on the blackboard, is the link, as
      for the dashboard;
    * `bin/run --record DIR`, which sets that section for the run.

  ## The black box

  One ring buffer (`ThinkingCap.BlackBox.RingBuffer`) per robot keeps its
  last minute in memory and dumps it to an MCAP file on an E-stop, a
  bumper contact, a module's layer giving up, a streak of deadline
  misses, a localization loss, or on request (`dump/3`, the console's
  `dump(:r1)`). It is on by default: the launcher starts one for every
  ADF started on this node, unless the ADF says `black_box: [enabled:
  false]` (or this app's `:black_box_by_default` env is false, as in the
  tests). `keep/2` starts one by hand; `dumps/1` lists the files and
  `dump_file/3` finds one by its name (for a download); `snapshot/2`
  copies what a black box holds (for the dashboard's timeline).
  """

  alias ThinkingCap.BlackBox.{Recorder, RingBuffer}

  @registry ThinkingCap.BlackBox.Registry
  @supervisor ThinkingCap.BlackBox.Recorders
  @ring_buffers ThinkingCap.BlackBox.RingBuffers

  @doc """
  Starts recording `robot` (options: `ThinkingCap.BlackBox.Recorder`,
  without `robot:`). Bad options are refused before anything starts.
  """
  @spec record(atom(), keyword()) :: {:ok, pid()} | {:error, term()}
  def record(robot, opts \\ []) when is_atom(robot) and is_list(opts) do
    opts = Keyword.put(opts, :robot, robot)

    with {:ok, _config} <- Recorder.validate(opts) do
      spec = Recorder.child_spec(Keyword.put(opts, :name, {:via, Registry, {@registry, robot}}))

      case DynamicSupervisor.start_child(@supervisor, spec) do
        {:error, {:already_started, _pid}} -> {:error, :already_recording}
        other -> other
      end
    end
  end

  @doc "Stops recording `robot`: its file is closed with its summary."
  @spec stop(atom()) :: :ok | {:error, :not_recording}
  def stop(robot) do
    case recorder(robot) do
      nil -> {:error, :not_recording}
      pid -> DynamicSupervisor.terminate_child(@supervisor, pid)
    end
  end

  @doc "The process recording `robot`, or nil."
  @spec recorder(atom()) :: pid() | nil
  def recorder(robot) do
    # the registry forgets a stopped recorder a moment after it is gone
    case Registry.lookup(@registry, robot) do
      [{pid, _}] -> if Process.alive?(pid), do: pid
      [] -> nil
    end
  end

  @doc "The robots being recorded on this node."
  @spec recording() :: [atom()]
  def recording,
    do: Registry.select(@registry, [{{:"$1", :_, :_}, [{:is_atom, :"$1"}], [:"$1"]}])

  @doc """
  Starts the black box of `robot` (options: `ThinkingCap.BlackBox.RingBuffer`,
  without `robot:`). Bad options are refused before anything starts.
  """
  @spec keep(atom(), keyword()) :: {:ok, pid()} | {:error, term()}
  def keep(robot, opts \\ []) when is_atom(robot) and is_list(opts) do
    opts = Keyword.put(opts, :robot, robot)

    with {:ok, _config} <- RingBuffer.validate(opts) do
      name = {:via, Registry, {@registry, {:ring, robot}}}
      spec = RingBuffer.child_spec(Keyword.put(opts, :name, name))

      case DynamicSupervisor.start_child(@ring_buffers, spec) do
        {:error, {:already_started, _pid}} -> {:error, :already_keeping}
        other -> other
      end
    end
  end

  @doc "Stops the black box of `robot` (a dump waiting is not written)."
  @spec forget(atom()) :: :ok | {:error, :not_keeping}
  def forget(robot) do
    case ring_buffer(robot) do
      nil -> {:error, :not_keeping}
      pid -> DynamicSupervisor.terminate_child(@ring_buffers, pid)
    end
  end

  @doc "The ring buffer of `robot` on this node, or nil."
  @spec ring_buffer(atom()) :: pid() | nil
  def ring_buffer(robot) do
    case Registry.lookup(@registry, {:ring, robot}) do
      [{pid, _}] -> pid
      [] -> nil
    end
  end

  @doc """
  Dumps the black box of `robot` now, for `reason`, and answers the
  file's path once it is written: the ring buffer's `after:` seconds
  later, or later if other triggers join the dump. Options: `timeout:`
  (ms, default 120 000).
  """
  @spec dump(atom(), term(), keyword()) :: {:ok, Path.t()} | {:error, term()}
  def dump(robot, reason \\ "request", opts \\ []) do
    case ring_buffer(robot) do
      nil -> {:error, :not_keeping}
      pid -> RingBuffer.dump(pid, reason, Keyword.get(opts, :timeout, 120_000))
    end
  end

  @doc """
  A copy of what the black box of `robot` holds now
  (`ThinkingCap.BlackBox.RingBuffer.snapshot/3`). Options: `tags:` the
  tuples' tags kept (default `:all`), `timeout:` (ms, default 30 000).
  """
  @spec snapshot(atom(), keyword()) :: {:ok, RingBuffer.snapshot()} | {:error, :not_keeping}
  def snapshot(robot, opts \\ []) do
    case ring_buffer(robot) do
      nil ->
        {:error, :not_keeping}

      pid ->
        {:ok, RingBuffer.snapshot(pid, Keyword.get(opts, :tags, :all), opts[:timeout] || 30_000)}
    end
  end

  @typedoc "A dump file, as `dumps/1` lists it."
  @type dump_file :: %{
          path: Path.t(),
          robot: atom(),
          bytes: non_neg_integer(),
          time: DateTime.t() | nil,
          reason: String.t()
        }

  @doc """
  The dumps of `robot` in its black box's directory (or `dir:`, default
  the running ring buffer's, else `"black_box"`), newest first.
  """
  @spec dumps(atom(), keyword()) :: [dump_file()]
  def dumps(robot, opts \\ []) do
    dir =
      opts[:dir] ||
        case ring_buffer(robot) do
          nil -> "black_box"
          pid -> RingBuffer.info(pid).dir
        end

    prefix = "#{robot}_"

    for path <- Path.wildcard(Path.join(Path.expand(dir), "*.mcap")),
        base = Path.basename(path, ".mcap"),
        String.starts_with?(base, prefix),
        [_, stamp, reason] <- [
          Regex.run(~r/^(\d{8}T\d{6}\.\d{3}Z)_(.*)$/, String.replace_prefix(base, prefix, ""))
        ] do
      %{path: path, robot: robot, bytes: File.stat!(path).size, time: time(stamp), reason: reason}
    end
    |> Enum.sort_by(&Path.basename(&1.path), :desc)
  end

  @doc """
  The dump of `robot` named `name` (a file name `dumps/2` lists, such as
  `r1_20260101T120000.000Z_estop.mcap`), in the same directory as
  `dumps/2` (options alike). Anything else, a path above all, is refused
  with a message that says why: the name is only ever looked up among
  the dumps listed, never opened as given.
  """
  @spec dump_file(atom(), term(), keyword()) :: {:ok, dump_file()} | {:error, String.t()}
  def dump_file(robot, name, opts \\ [])

  def dump_file(robot, name, opts) when is_binary(name) do
    if byte_size(name) <= 255 and name =~ ~r/\A[A-Za-z0-9][A-Za-z0-9_.-]*\.mcap\z/ do
      case Enum.find(dumps(robot, opts), &(Path.basename(&1.path) == name)) do
        nil -> {:error, "no dump #{inspect(name)} of #{robot}"}
        dump -> {:ok, dump}
      end
    else
      {:error,
       "a dump's name is a file name such as #{robot}_20260101T120000.000Z_estop.mcap, " <>
         "not #{inspect(name, printable_limit: 80)}"}
    end
  end

  def dump_file(robot, name, _opts),
    do: {:error, "a dump's name is a string, not #{inspect(name, limit: 5)} (#{robot})"}

  defp time(
         <<y::binary-4, mo::binary-2, d::binary-2, "T", h::binary-2, mi::binary-2, s::binary-2,
           ".", ms::binary-3, "Z">>
       ) do
    case DateTime.from_iso8601("#{y}-#{mo}-#{d}T#{h}:#{mi}:#{s}.#{ms}Z") do
      {:ok, dt, 0} -> dt
      _ -> nil
    end
  end
end
