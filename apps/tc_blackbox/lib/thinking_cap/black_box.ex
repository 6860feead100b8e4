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
  tests). `keep/2` starts one by hand; `dumps/1` lists the files.
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
