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
  """

  alias ThinkingCap.BlackBox.Recorder

  @registry ThinkingCap.BlackBox.Registry
  @supervisor ThinkingCap.BlackBox.Recorders

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
    case Registry.lookup(@registry, robot) do
      [{pid, _}] -> pid
      [] -> nil
    end
  end

  @doc "The robots being recorded on this node."
  @spec recording() :: [atom()]
  def recording, do: Registry.select(@registry, [{{:"$1", :_, :_}, [], [:"$1"]}])
end
