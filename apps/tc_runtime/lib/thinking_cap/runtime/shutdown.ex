defmodule ThinkingCap.Runtime.Shutdown do
  @moduledoc """
  How a node stops: its robots first, then everything else, within a
  bounded time.

  `begin/1` stops every robot of the node (`ThinkingCap.Cycle.stop_all/0`:
  each periodic activity's fallback applied at once, a serial robot's stop
  frame written on its wire by the timing worker) and starts a watchdog
  that halts the VM if it is still up `timeout` ms later (default 4.5
  s). It runs once; later calls do nothing.

  The node promises to be gone within 5 s of the request to stop. The
  watchdog starts when `begin/1` runs, after the request has reached the
  node, and a halt takes its own moment: with a watchdog of 5 s, a node
  whose orderly stop ran long (a fault test beside a CI run's compile)
  was still up 5 s after the request. Half a second is their margin.

  It is called:

    * on **SIGTERM** (systemd, Docker, `kill`, `bin/run`'s Ctrl-C): this
      module replaces OTP's default signal handler, which would start the
      orderly `init:stop/0` with the robot still driving; here the robots
      stop first, then `init:stop/0`;
    * when the top application stops (a release's `stop`, `init:stop/0`
      from a shell): its `prep_stop` calls `begin/1` before anything else
      is stopped.

  Other signals keep OTP's meaning: SIGUSR1 writes a crash dump and
  halts, SIGQUIT halts.
  """

  @behaviour :gen_event
  require Logger

  @key {__MODULE__, :begun}

  @doc """
  Installs the signal handler (the runtime's application does, at start).
  Safe to call again.
  """
  @spec install() :: :ok
  def install do
    handlers = :gen_event.which_handlers(:erl_signal_server)

    cond do
      __MODULE__ in handlers ->
        :ok

      :erl_signal_handler in handlers ->
        :ok =
          :gen_event.swap_handler(:erl_signal_server, {:erl_signal_handler, []}, {__MODULE__, []})

      true ->
        :ok = :gen_event.add_handler(:erl_signal_server, __MODULE__, [])
    end
  end

  @doc """
  Stops the node's robots and arms the watchdog (once). Returns the names
  of the periodic activities stopped, `[]` on a later call.
  """
  @spec begin(keyword()) :: [term()]
  def begin(opts \\ []) do
    if :persistent_term.get(@key, false) do
      []
    else
      :persistent_term.put(@key, true)
      stopped = ThinkingCap.Cycle.stop_all()
      timeout = Keyword.get(opts, :timeout, 4_500)
      watchdog(timeout)

      Logger.notice(
        "stopping: robots stopped (#{Enum.map_join(stopped, ", ", &inspect/1)}); " <>
          "the node halts in #{timeout} ms at the latest"
      )

      stopped
    end
  end

  @doc "Whether `begin/1` has run on this node."
  @spec begun?() :: boolean()
  def begun?, do: :persistent_term.get(@key, false)

  defp watchdog(timeout) do
    spawn(fn ->
      Process.flag(:priority, :high)
      Process.sleep(timeout)
      :erlang.halt(1, flush: false)
    end)
  end

  ## :gen_event (the signal handler)

  @impl :gen_event
  def init(_args), do: {:ok, nil}

  @impl :gen_event
  def handle_event(:sigterm, state) do
    Logger.notice("SIGTERM received: stopping the robots, then the node")
    begin()
    :ok = :init.stop()
    {:ok, state}
  end

  def handle_event(:sigusr1, _state), do: :erlang.halt(~c"Received SIGUSR1")
  def handle_event(:sigquit, _state), do: :erlang.halt()
  def handle_event(_signal, state), do: {:ok, state}

  @impl :gen_event
  def handle_call(_request, state), do: {:ok, :ok, state}

  @impl :gen_event
  def handle_info(_message, state), do: {:ok, state}
end
