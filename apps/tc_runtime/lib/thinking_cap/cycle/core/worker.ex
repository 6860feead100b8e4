defmodule ThinkingCap.Cycle.Core.Worker do
  @moduledoc false
  # The timing worker's port, owned by ThinkingCap.Cycle: started (and
  # told which of the BEAM's threads to boost), sent frames, closed. Any
  # process sends results straight to it (send_result/1), through the
  # port kept in a persistent term.
  require Logger

  alias ThinkingCap.Cycle.Core.Protocol
  alias ThinkingCap.Runtime.Scheduling

  @port_key {ThinkingCap.Cycle, :port}

  # the worker's MAX_WAKE_EARLY_US
  @max_wake_early_us 2000

  @doc """
  Starts the worker and waits for its hello; names the threads to boost.
  Returns `{port, status, boost}`.
  """
  def open do
    path = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")
    # :eof: the worker's output closing is the first sign of its death
    # (its exit status comes later, through the child-process helper)
    args = ["--wake-early-us", Integer.to_string(wake_early_us())]

    port =
      Port.open({:spawn_executable, path}, [:binary, {:packet, 4}, :exit_status, :eof, args: args])

    :persistent_term.put(@port_key, port)

    status =
      receive do
        {^port, {:data, <<?H, _::binary>> = hello}} ->
          {:hello, status} = Protocol.decode(hello)
          Logger.info("timing worker: #{status.message}")
          status
      after
        5000 -> raise "the timing worker did not say hello within 5 s"
      end

    boost = Scheduling.release_boost()
    Port.command(port, Protocol.boost(boost))
    {port, status, boost}
  end

  @doc """
  How early the worker's thread wakes before each release, in µs
  (`:tc_runtime, :wake_early_us`, default 100): see `ThinkingCap.Cycle`.
  """
  def wake_early_us do
    case Application.get_env(:tc_runtime, :wake_early_us, 100) do
      us when is_integer(us) and us in 0..@max_wake_early_us ->
        us

      other ->
        raise ArgumentError,
              ":tc_runtime, :wake_early_us must be an integer from 0 to #{@max_wake_early_us} " <>
                "(microseconds), not #{inspect(other)}"
    end
  end

  @doc "Sends a frame to the worker; nothing when there is none."
  def command(nil, _frame), do: :ok
  def command(port, frame), do: Port.command(port, frame)

  @doc "Sends a result from any process; nothing when the worker is down."
  def send_result(frame) do
    case :persistent_term.get(@port_key, nil) do
      nil -> :ok
      port -> Port.command(port, frame)
    end

    :ok
  rescue
    ArgumentError -> :ok
  end

  @doc "Closes a port whose worker died (or is about to be replaced)."
  def close(port) do
    Port.close(port)
  rescue
    ArgumentError -> :ok
  end

  @doc "The port is gone for good (its owner stops)."
  def forget, do: :persistent_term.erase(@port_key)

  @doc "The worker's OS pid."
  def os_pid(port), do: with({:os_pid, pid} <- Port.info(port, :os_pid), do: pid)

  @doc "Puts back the threads a dead worker may have left boosted."
  def undo_boost(boost), do: Scheduling.undo_boost(boost)
end
