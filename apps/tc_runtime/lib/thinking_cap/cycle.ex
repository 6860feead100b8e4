defmodule ThinkingCap.Cycle do
  @moduledoc """
  The periodic control cycle: the BEAM side of the C timing worker
  (`apps/tc_runtime/c_src/tc_timing.c`, built by the app's own compiler
  step into `priv/bin/tc_timing`).

  The worker releases each periodic activity on absolute `CLOCK_MONOTONIC`
  deadlines, at `SCHED_FIFO` with its memory locked when the OS grants it
  (`status/0` says whether it did). Each release reaches the activity's
  owner as

      {:tc_cycle, :release, name, %{id: id, cycle: n, scheduled_ns: t, released_ns: t}}

  and the owner answers with `result/2` (the command to apply), straight to
  the worker's port. If no result arrives by the activity's deadline, the
  worker applies the activity's **fallback** command in that same cycle.
  Every applied command, fresh or fallback, reaches the owner and every
  process that called `subscribe/1` as

      {:tc_cycle, :applied, name, %{cycle: n, kind: :fresh | :fallback | :late, command: term, response_us: float}}

  (`:late` reports a result that came after its fallback; it is not
  applied). A removed activity's fallback is applied at once (its module
  stopped or crashed: no fresh command will come). If the BEAM dies, the
  worker applies every fallback and exits.
  If the worker dies, this process starts a new one, adds every activity
  again, and tells subscribers that each activity's fallback is applied:
  the robot stays stopped until a fresh command.

  Statistics per activity (`ThinkingCap.Cycle.Stats`) are available from
  `timing/0` and published once a second on the blackboard as
  `{:timing, name, summary}`.
  """
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Cycle.Stats

  @type name :: atom()
  @type release :: %{
          id: non_neg_integer(),
          cycle: non_neg_integer(),
          scheduled_ns: integer(),
          released_ns: integer()
        }

  @type applied :: %{
          cycle: non_neg_integer(),
          kind: :fresh | :fallback | :late,
          command: term(),
          response_us: float()
        }

  @kinds %{0 => :fresh, 1 => :fallback, 2 => :late}

  @doc "Starts the cycle and its timing worker (registered as `#{inspect(__MODULE__)}`)."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []), do: GenServer.start_link(__MODULE__, opts, name: __MODULE__)

  @doc """
  Adds a periodic activity: `period` and `deadline` in seconds, `priority`
  1..99 (releases due together go highest first), `fallback` (the command
  applied on a missed deadline, default `:stop`), `owner` (the process that
  gets the releases, default the caller).
  """
  @spec add(name(), keyword()) :: :ok
  def add(name, opts),
    do: GenServer.call(__MODULE__, {:add, name, Keyword.put_new(opts, :owner, self())})

  @doc "Removes a periodic activity."
  @spec remove(name()) :: :ok
  def remove(name), do: GenServer.call(__MODULE__, {:remove, name})

  @doc """
  Sends the result of a release (the command to apply) to the worker. Safe
  to call when the worker is down: the fallback is applied then anyway.
  """
  @spec result(release(), term()) :: :ok
  def result(%{id: id, cycle: cycle}, command) do
    frame = <<?C, id::16, cycle::32, :erlang.term_to_binary(command)::binary>>

    case :persistent_term.get({__MODULE__, :port}, nil) do
      nil -> :ok
      port -> Port.command(port, frame)
    end

    :ok
  rescue
    ArgumentError -> :ok
  end

  @doc "Records how long the module took to compute the result of `release` (ns)."
  @spec record_cpu(release(), non_neg_integer()) :: :ok
  def record_cpu(%{id: id}, ns) do
    send(__MODULE__, {:cpu, id, ns})
    :ok
  end

  @doc """
  Sends the caller every command applied for activity `name`, from now
  until the caller exits: across the activity's removal and re-adding (a
  module that restarts), and for an activity not added yet.
  """
  @spec subscribe(name()) :: :ok
  def subscribe(name), do: GenServer.call(__MODULE__, {:subscribe, name, self()})

  @doc "Whether the OS granted SCHED_FIFO and mlockall to the worker, and its own words."
  @spec status() :: %{
          sched_fifo: boolean(),
          mlockall: boolean(),
          message: String.t(),
          restarts: non_neg_integer()
        }
  def status, do: GenServer.call(__MODULE__, :status)

  @doc "Timing statistics of every activity (see `ThinkingCap.Cycle.Stats.summary/1`)."
  @spec timing() :: %{name() => map()}
  def timing, do: GenServer.call(__MODULE__, :timing)

  @doc false
  # The worker's OS pid (tests kill it).
  @spec worker_os_pid() :: non_neg_integer() | nil
  def worker_os_pid, do: GenServer.call(__MODULE__, :os_pid)

  ## Server

  @impl true
  def init(opts) do
    # the cycle's own messages go before ordinary work
    Process.flag(:priority, :high)
    Process.flag(:trap_exit, true)
    publish_ms = Keyword.get(opts, :publish_every, 1000)
    if publish_ms, do: :timer.send_interval(publish_ms, :publish)

    state = %{
      port: nil,
      status: nil,
      activities: %{},
      ids: %{},
      next_id: 1,
      restarts: 0,
      watchers: %{}
    }

    {:ok, open(state)}
  end

  @impl true
  def handle_call({:add, name, opts}, _from, state) do
    period = seconds!(opts, :period)
    deadline = Keyword.get(opts, :deadline, period)
    priority = Keyword.get(opts, :priority, 50)
    fallback = Keyword.get(opts, :fallback, :stop)

    unless deadline > 0 and deadline <= period and priority in 1..99 do
      raise ArgumentError,
            "activity #{inspect(name)}: need 0 < deadline <= period and priority 1..99"
    end

    {id, state} = id_for(state, name)
    owner = Keyword.fetch!(opts, :owner)
    Process.monitor(owner)

    activity = %{
      id: id,
      name: name,
      period_ns: round(period * 1.0e9),
      deadline_ns: round(deadline * 1.0e9),
      priority: priority,
      fallback: fallback,
      owner: owner,
      stats: Stats.new(round(period * 1.0e9))
    }

    send_add(state.port, activity)
    {:reply, :ok, put_in(state.activities[id], activity)}
  end

  def handle_call({:remove, name}, _from, state), do: {:reply, :ok, remove_activity(state, name)}

  def handle_call({:subscribe, name, pid}, _from, state) do
    Process.monitor(pid)
    watchers = Map.update(state.watchers, name, MapSet.new([pid]), &MapSet.put(&1, pid))
    {:reply, :ok, %{state | watchers: watchers}}
  end

  def handle_call(:status, _from, state),
    do: {:reply, Map.put(state.status, :restarts, state.restarts), state}

  def handle_call(:timing, _from, state) do
    {:reply, Map.new(state.activities, fn {_, a} -> {a.name, Stats.summary(a.stats)} end), state}
  end

  def handle_call(:os_pid, _from, state) do
    {:reply, with({:os_pid, pid} <- Port.info(state.port, :os_pid), do: pid), state}
  end

  @impl true
  def handle_info({port, {:data, frame}}, %{port: port} = state),
    do: {:noreply, handle_frame(frame, state)}

  def handle_info({port, :eof}, %{port: port} = state) do
    Logger.error(
      "timing worker closed its output (it died); restarting it, robot stopped until a fresh command"
    )

    close_port(port)
    {:noreply, restart(state)}
  end

  def handle_info({port, {:exit_status, status}}, %{port: port} = state) do
    Logger.error(
      "timing worker exited with status #{status}; restarting it, robot stopped until a fresh command"
    )

    # with :eof the port outlives its program until closed
    close_port(port)
    {:noreply, restart(state)}
  end

  def handle_info({:EXIT, port, reason}, %{port: port} = state) do
    Logger.error("timing worker port closed (#{inspect(reason)}); restarting it")
    {:noreply, restart(state)}
  end

  def handle_info({:EXIT, _other, _reason}, state), do: {:noreply, state}

  def handle_info({:DOWN, _ref, :process, pid, _reason}, state) do
    state =
      Enum.reduce(state.activities, state, fn
        {_id, %{owner: ^pid, name: name}}, st -> remove_activity(st, name)
        _other, st -> st
      end)

    watchers =
      for {name, pids} <- state.watchers,
          pids = MapSet.delete(pids, pid),
          MapSet.size(pids) > 0,
          into: %{},
          do: {name, pids}

    {:noreply, %{state | watchers: watchers}}
  end

  def handle_info({:cpu, id, ns}, state) do
    case state.activities do
      %{^id => a} -> {:noreply, put_in(state.activities[id].stats, Stats.cpu(a.stats, ns))}
      _ -> {:noreply, state}
    end
  end

  def handle_info(:publish, state) do
    for {_id, a} <- state.activities,
        do: Blackboard.out({:timing, a.name, Stats.summary(a.stats)}, key: {:timing, a.name})

    {:noreply, state}
  end

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def terminate(_reason, state) do
    if state.port, do: Port.close(state.port)
    :persistent_term.erase({__MODULE__, :port})
    :ok
  catch
    _, _ -> :ok
  end

  ## Frames

  defp handle_frame(<<?L, id::16, cycle::32, scheduled::64, released::64>>, state) do
    case state.activities do
      %{^id => a} ->
        send(
          a.owner,
          {:tc_cycle, :release, a.name,
           %{id: id, cycle: cycle, scheduled_ns: scheduled, released_ns: released}}
        )

        put_in(state.activities[id].stats, Stats.release(a.stats, scheduled, released))

      _ ->
        state
    end
  end

  defp handle_frame(<<?P, id::16, cycle::32, kind, response::64, command::binary>>, state) do
    case state.activities do
      %{^id => a} ->
        kind = Map.fetch!(@kinds, kind)
        command = if command == "", do: nil, else: :erlang.binary_to_term(command)
        event = %{cycle: cycle, kind: kind, command: command, response_us: response / 1000}
        tell(state, a, event)
        put_in(state.activities[id].stats, Stats.applied(a.stats, kind, response))

      _ ->
        state
    end
  end

  defp handle_frame(<<?H, fifo, mlock, text::binary>>, state) do
    status = %{sched_fifo: fifo == 1, mlockall: mlock == 1, message: text}
    Logger.info("timing worker: #{text}")
    %{state | status: status}
  end

  defp handle_frame(<<?E, text::binary>>, state) do
    Logger.error("timing worker refused a frame: #{text}")
    state
  end

  defp handle_frame(other, state) do
    Logger.error("unexpected frame from the timing worker: #{inspect(other, limit: 20)}")
    state
  end

  ## Worker

  defp open(state) do
    path = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")
    # :eof: the worker's output closing is the first sign of its death
    # (its exit status comes later, through the child-process helper)
    port = Port.open({:spawn_executable, path}, [:binary, {:packet, 4}, :exit_status, :eof])
    :persistent_term.put({__MODULE__, :port}, port)

    receive do
      {^port, {:data, <<?H, _::binary>> = hello}} -> handle_frame(hello, %{state | port: port})
    after
      5000 -> raise "the timing worker did not say hello within 5 s"
    end
  end

  defp close_port(port) do
    Port.close(port)
  rescue
    ArgumentError -> :ok
  end

  defp restart(state) do
    # the dead worker applies nothing: every activity's fallback holds from
    # now (its owner drives it), before a new worker is even spawned
    for {_id, a} <- state.activities,
        do: tell(state, a, %{cycle: 0, kind: :fallback, command: a.fallback, response_us: 0.0})

    state = open(%{state | port: nil, restarts: state.restarts + 1})

    # every activity again; until its next fresh result, its fallback holds
    for {_id, a} <- state.activities, do: send_add(state.port, a)

    state
  end

  # an applied command goes to the activity's owner and its watchers
  defp tell(state, a, event) do
    message = {:tc_cycle, :applied, a.name, event}
    send(a.owner, message)

    for pid <- Map.get(state.watchers, a.name, []), pid != a.owner, do: send(pid, message)
    :ok
  end

  defp send_add(port, a) do
    fallback = :erlang.term_to_binary(a.fallback)

    Port.command(
      port,
      <<?A, a.id::16, a.period_ns::64, a.deadline_ns::64, a.priority, fallback::binary>>
    )
  end

  # The worker applies a removed activity's fallback; its subscribers hear
  # it here, since the activity is gone when the worker's frame arrives.
  defp remove_activity(state, name) do
    case state.ids do
      %{^name => id} when is_map_key(state.activities, id) ->
        a = state.activities[id]
        if state.port, do: Port.command(state.port, <<?R, id::16>>)
        tell(state, a, %{cycle: 0, kind: :fallback, command: a.fallback, response_us: 0.0})
        %{state | activities: Map.delete(state.activities, id)}

      _ ->
        state
    end
  end

  defp id_for(state, name) do
    case state.ids do
      %{^name => id} ->
        {id, state}

      _ ->
        {state.next_id,
         %{state | ids: Map.put(state.ids, name, state.next_id), next_id: state.next_id + 1}}
    end
  end

  defp seconds!(opts, key) do
    case Keyword.fetch(opts, key) do
      {:ok, s} when is_number(s) and s > 0 ->
        s

      _ ->
        raise ArgumentError,
              "activity needs #{key}: seconds (a positive number), got #{inspect(opts[key])}"
    end
  end
end
