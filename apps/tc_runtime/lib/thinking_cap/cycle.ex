defmodule ThinkingCap.Cycle do
  @moduledoc """
  The periodic control cycle: the BEAM side of the C timing worker
  (`apps/tc_runtime/c_src/tc_timing.c`, built by the app's own compiler
  step into `priv/bin/tc_timing`).

  The worker releases each periodic activity on absolute `CLOCK_MONOTONIC`
  deadlines, at `SCHED_FIFO` with its memory locked when the OS grants it
  (`status/0` says whether it did). Each release reaches the activity's
  owner as

      {:tc_cycle, :release, name, %{id: id, cycle: n, scheduled_ns: t, released_ns: t,
                                    timer_late_ns: ns}}

  and the owner answers with `result/2` (the command to apply), straight to
  the worker's port. If no result arrives by the activity's deadline, the
  worker applies the activity's **fallback** command in that same cycle.
  Every applied command, fresh or fallback, reaches the owner and every
  process that called `subscribe/1` as

      {:tc_cycle, :applied, name, %{cycle: n, kind: :fresh | :fallback | :late, command: term,
                                    wired: boolean, response_us: float, applied_ns: t | nil}}

  (`:late` reports a result that came after its fallback; it is not
  applied). `applied_ns` is when the worker applied the command, on its
  `CLOCK_MONOTONIC` (the clock of `released_ns`): the release's time plus
  the response, exact where the time the report reaches a process is not.
  It is nil for late results and for the fallbacks told on a worker's
  restart. A removed activity's fallback is applied at once (its module
  stopped or crashed: no fresh command will come). If the BEAM dies, the
  worker applies every fallback and exits.
  If the worker dies, this process starts a new one, adds every activity
  again, and tells subscribers that each activity's fallback is applied:
  the robot stays stopped until a fresh command.

  ## Lead

  A release reaches its owner a little after the worker's thread wakes:
  the frame crosses the port and two BEAM processes, 0.2 to 0.3 ms on this
  project's 2-core test machine, more under load. An activity added with
  `lead: seconds` is released that much early, with `scheduled_ns` still
  the instant it is due; the owner calls `await_release/1`, which waits,
  busy, until that instant (`ThinkingCap.Runtime`'s hosts do). So
  `handle_cycle/2` starts within microseconds of `scheduled_ns` whenever
  the delivery took less than the lead, at the price of a core spinning
  for what is left of the lead each cycle. The deadline still counts from
  `scheduled_ns`. `released_ns` is when the worker released it: with a
  lead, before `scheduled_ns`.

  ## Waking early

  A thread's timer wakes it a little late: tens of microseconds as a
  rule, hundreds now and then on a virtual machine (`cyclictest` shows
  the same). The worker's timing thread therefore sets its timer
  `:tc_runtime, :wake_early_us` (default 100, at most 2000, 0 turns it
  off) before each release and spins on the clock to the instant. A
  release leaves on time whenever the thread woke less than that late,
  and never leaves early. The price is up to that long of one core
  spinning per release: 1 % of a core for a 100 Hz activity, more for a
  node that hosts many (a simulated fleet may want 0). Deadlines are
  waited for without it: a fallback does not need the microsecond, and
  most deadlines find their result in. Each release says how late the
  timer woke the thread (`timer_late_ns`), and `timing/0` gives its
  statistics (`timer_late_us`), so the machine's own wake-up latency
  stays visible.

  ## Wires

  An activity may hand its device's command path to the worker:
  `attach_wire/3` makes the worker open a device (a serial line, a pty, a
  FIFO: opaque bytes, this layer knows no protocol) write-only, without
  touching its line settings. The owner then answers a release with
  `result/3`, the command and the bytes to put on the line; the worker
  writes them when it applies the result, and writes the wire's
  **fallback bytes** whenever it applies the fallback: a missed deadline,
  the activity removed (its module crashed), the BEAM gone. A missed
  deadline thus puts the stop frame on the line in that same cycle, from
  the worker, whatever the BEAM does. `wired: true` in an applied event
  says the command's bytes went on the line whole; `false` (no wire, the
  line down or full, the worker restarted) means whoever drives the
  device must write them itself. The worker never blocks on a line: bytes
  it does not take at once are dropped and reported; a line that went
  away is reopened every 100 ms on later writes, but only while its path
  names the very device first opened (same device, inode and, for a
  character device, inode change time). A path that names another device
  now (a replugged adapter, a later pty that got the same `/dev/pts/N`, a
  symlink pointed elsewhere) is never written to; that is reported once,
  and only the owner can hand the new device over, by attaching the wire
  again. Wires are attached again when the worker is restarted (the
  device their path names then). A wire ends, and the worker never opens
  its path again, when it is detached, replaced, or its activity removed
  (the module stopped for good or crashed: its fallback bytes are written
  first; a module restarted attaches its wire anew in its `init/2`).
  `timing/0` gives each activity's `wire` (its device or `nil`) and
  `wire_errors`.

  ## The release boost

  While any activity's result is pending, the worker holds the BEAM's
  scheduler threads at `SCHED_FIFO` 20 (the poller at 21) and puts them
  back when none is, so that a periodic module's release and work go
  before other programs' low real-time threads
  (`ThinkingCap.Runtime.Scheduling` says why and how to turn it off).
  This process names the threads to the worker when it starts it; a
  worker killed during a boost leaves them boosted, and this process puts
  them back before it starts the next one.

  Statistics per activity (`ThinkingCap.Cycle.Stats`) are available from
  `timing/0` and published once a second on the blackboard as
  `{:timing, name, summary}` (`ThinkingCap.Tuples.timing/2`). A process
  of their own keeps them, linked to this one, so that this one's heap,
  through which every release passes, stays small: its collections take
  microseconds and stay on its own scheduler (OTP moves those of 128K
  words or more to a dirty one, see `ThinkingCap.Runtime.Scheduling`).
  """
  use GenServer
  require Logger

  alias ThinkingCap.Cycle.{Clock, Stats}

  alias ThinkingCap.Cycle.Core.{
    Activities,
    Fallbacks,
    Protocol,
    Releases,
    Statistics,
    Wires,
    Worker
  }

  @type name :: atom()
  @type release :: %{
          id: non_neg_integer(),
          cycle: non_neg_integer(),
          scheduled_ns: integer(),
          released_ns: integer(),
          timer_late_ns: non_neg_integer()
        }

  @type applied :: %{
          cycle: non_neg_integer(),
          kind: :fresh | :fallback | :late,
          command: term(),
          wired: boolean(),
          response_us: float(),
          applied_ns: integer() | nil
        }

  # the worker's limit on a wire's bytes
  @max_wire Wires.max_bytes()
  # the timing worker's table (MAX_ACTIVITIES in c_src/tc_timing.c)
  @max_activities 256
  # a lead is spent spinning: a few times the delivery it makes up for
  @max_lead 0.005

  @doc "Starts the cycle and its timing worker (registered as `#{inspect(__MODULE__)}`)."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []), do: GenServer.start_link(__MODULE__, opts, name: __MODULE__)

  @doc """
  Adds a periodic activity: `period` and `deadline` in seconds, `priority`
  1..99 (releases due together go highest first), `fallback` (the command
  applied on a missed deadline, default `:stop`), `owner` (the process that
  gets the releases, default the caller), `lead` (seconds, default 0, at
  most #{@max_lead}; see "Lead" in the moduledoc; `deadline + lead` at
  most the period).

  Adding a name again takes the activity over (a restarted module) unless
  another live process owns it: that is refused with the owner's pid.
  A node holds at most #{@max_activities} activities; more are refused.
  """
  @spec add(name(), keyword()) ::
          :ok | {:error, {:name_taken, pid()} | {:too_many_activities, pos_integer()} | :stopping}
  def add(name, opts) do
    # checked here, in the caller: bad options raise there, never in the
    # server that holds every activity's releases
    period = seconds!(opts, :period)
    deadline = Keyword.get(opts, :deadline, period)
    lead = Keyword.get(opts, :lead, 0)
    priority = Keyword.get(opts, :priority, 50)

    unless is_number(deadline) and deadline > 0 and is_number(lead) and lead >= 0 and
             lead <= @max_lead and deadline + lead <= period and priority in 1..99 do
      raise ArgumentError,
            "activity #{inspect(name)}: need 0 < deadline, 0 <= lead <= #{@max_lead}, " <>
              "deadline + lead <= period and priority 1..99"
    end

    GenServer.call(__MODULE__, {:add, name, Keyword.put_new(opts, :owner, self())})
  end

  @doc "Removes a periodic activity."
  @spec remove(name()) :: :ok
  def remove(name), do: GenServer.call(__MODULE__, {:remove, name})

  @doc """
  Stops every robot of this node: each periodic activity is removed, so
  the worker applies its fallback now (the stop command, and a serial
  robot's stop frame on its wire) and releases it no more; activities
  added afterwards are refused (`{:error, :stopping}`). For a node that
  is about to shut down (`ThinkingCap.Runtime.Shutdown`). Returns the
  names of the activities stopped; `[]` when the cycle is not running.
  """
  @spec stop_all() :: [name()]
  def stop_all do
    if Process.whereis(__MODULE__), do: GenServer.call(__MODULE__, :stop_all), else: []
  catch
    :exit, _ -> []
  end

  @doc """
  Waits, busy, until the release's `scheduled_ns` on the worker's clock
  (`ThinkingCap.Cycle.Clock`): a release of an activity with a `lead`
  comes early (at most #{@max_lead * 1000} ms). Returns at once for a
  release that is due or late.
  """
  @spec await_release(release()) :: :ok
  def await_release(%{scheduled_ns: due}), do: spin_until(due)

  defp spin_until(due), do: if(Clock.now_ns() < due, do: spin_until(due), else: :ok)

  @doc """
  Sends the result of a release (the command to apply) to the worker. Safe
  to call when the worker is down: the fallback is applied then anyway.
  """
  @spec result(release(), term()) :: :ok
  def result(%{id: id, cycle: cycle}, command),
    do: Worker.send_result(Protocol.result(id, cycle, command))

  @doc """
  Like `result/2`, with the bytes to put on the activity's wire
  (`attach_wire/3`) when the worker applies the command. Bytes over
  #{@max_wire}, or not iodata, are refused with an error logged, and nothing
  is sent: the fallback is applied at the deadline.
  """
  @spec result(release(), term(), iodata()) :: :ok
  def result(%{id: id, cycle: cycle}, command, wire_bytes) do
    case IO.iodata_to_binary(wire_bytes) do
      wire when byte_size(wire) <= @max_wire ->
        Worker.send_result(Protocol.wired_result(id, cycle, wire, command))

      wire ->
        Logger.error(
          "cycle #{cycle} of activity #{id}: #{byte_size(wire)} wire bytes, over #{@max_wire}: " <>
            "result not sent, the fallback will be applied"
        )

        :ok
    end
  rescue
    ArgumentError ->
      Logger.error(
        "cycle #{cycle} of activity #{id}: the wire bytes are not iodata " <>
          "(#{inspect(wire_bytes, limit: 5)}): result not sent, the fallback will be applied"
      )

      :ok
  end

  @doc """
  Hands activity `name`'s command path to the worker: it opens `device`
  (write-only, non-blocking, its line settings left alone) and keeps
  `fallback` bytes (at most #{@max_wire}) to write whenever it applies the
  activity's fallback. Replaces a wire attached before. Waits for the
  worker's answer: `{:error, message}` names the device and what failed.
  """
  @spec attach_wire(name(), Path.t(), iodata()) :: :ok | {:error, String.t()}
  def attach_wire(name, device, fallback),
    do: GenServer.call(__MODULE__, {:attach_wire, name, device, fallback}, 15_000)

  @doc "Takes activity `name`'s wire from the worker (it closes the device)."
  @spec detach_wire(name()) :: :ok
  def detach_wire(name), do: GenServer.call(__MODULE__, {:detach_wire, name})

  @doc "Records how long the module took to compute the result of `release` (ns, wall clock)."
  @spec record_cpu(release(), non_neg_integer()) :: :ok
  def record_cpu(%{id: id}, ns), do: Statistics.cpu(id, ns)

  @doc """
  Sends the caller every command applied for activity `name`, from now
  until the caller exits: across the activity's removal and re-adding (a
  module that restarts), and for an activity not added yet.
  """
  @spec subscribe(name()) :: :ok
  def subscribe(name), do: GenServer.call(__MODULE__, {:subscribe, name, self()})

  @doc """
  Whether the OS granted SCHED_FIFO and mlockall to the worker, and its
  own words; `restarts` of the worker; `statistics_dropped`, the timing
  samples dropped because the node was too busy for the statistics'
  keeper (its queue is bounded: `timing/0` then undercounts).
  """
  @spec status() :: %{
          sched_fifo: boolean(),
          mlockall: boolean(),
          message: String.t(),
          restarts: non_neg_integer(),
          statistics_dropped: non_neg_integer()
        }
  def status, do: GenServer.call(__MODULE__, :status)

  @doc "Timing statistics of every activity (see `ThinkingCap.Cycle.Stats.summary/1`)."
  @spec timing() :: %{name() => map()}
  def timing do
    activities = GenServer.call(__MODULE__, :wires, 120_000)
    summaries = Statistics.summaries()

    Map.new(activities, fn {name, %{period_ns: period_ns} = a} ->
      summary = Map.get_lazy(summaries, name, fn -> Stats.summary(Stats.new(period_ns)) end)
      {name, Map.merge(summary, Map.delete(a, :period_ns))}
    end)
  end

  @doc false
  # Each activity's wire and period, by name (the statistics' keeper
  # publishes them with its figures); empty when the cycle is not running.
  @spec wires() :: %{name() => map()}
  def wires do
    GenServer.call(__MODULE__, :wires)
  catch
    :exit, _ -> %{}
  end

  @doc false
  # The worker's OS pid (tests kill it).
  @spec worker_os_pid() :: non_neg_integer() | nil
  def worker_os_pid, do: GenServer.call(__MODULE__, :os_pid)

  ## Server

  # what a release and its result go through, loaded before the first
  # release: loading a module on first call waits for the code server and
  # the file system (a first release came 23 ms late under load, most
  # likely for that)
  @release_path [Activities, Fallbacks, Protocol, Releases, Statistics, Worker, Clock]

  @impl true
  def init(opts) do
    Enum.each(@release_path, &Code.ensure_loaded!/1)
    # the cycle's own messages go before ordinary work
    Process.flag(:priority, :high)
    Process.flag(:trap_exit, true)
    # the worker's frames wait off the heap: a queue that grew during a
    # stall is not copied by each collection
    Process.flag(:message_queue_data, :off_heap)
    publish_ms = Keyword.get(opts, :publish_every, 1000)

    state = %{
      statistics: nil,
      publish_ms: publish_ms,
      port: nil,
      status: nil,
      activities: %{},
      ids: %{},
      next_id: 1,
      restarts: 0,
      watchers: %{},
      # wire attachments waiting for the worker's answer, by activity id
      attaching: %{},
      stopping: false,
      # the threads the worker boosts while a result is pending
      boost: []
    }

    {:ok, state |> start_statistics() |> open()}
  end

  @impl true
  def handle_call({:add, _name, _opts}, _from, %{stopping: true} = state),
    do: {:reply, {:error, :stopping}, state}

  def handle_call({:add, name, opts}, _from, state) do
    period = Keyword.fetch!(opts, :period)
    deadline = Keyword.get(opts, :deadline, period)
    lead = Keyword.get(opts, :lead, 0)
    priority = Keyword.get(opts, :priority, 50)
    fallback = Keyword.get(opts, :fallback, :stop)
    owner = Keyword.fetch!(opts, :owner)

    case Activities.live_owner(state, name) do
      other when is_pid(other) and other != owner ->
        {:reply, {:error, {:name_taken, other}}, state}

      _none_or_same ->
        if map_size(state.activities) >= @max_activities and
             Activities.id_of(state, name) == :error,
           # the worker's table is full: it would refuse the activity
           do: {:reply, {:error, {:too_many_activities, @max_activities}}, state},
           else:
             {:reply, :ok,
              Activities.add(state, name, owner, period, deadline, lead, priority, fallback)}
    end
  end

  def handle_call({:remove, name}, _from, state),
    do: {:reply, :ok, Fallbacks.remove(state, name)}

  def handle_call(:stop_all, _from, state) do
    names = Activities.names(state)
    state = Enum.reduce(names, state, &Fallbacks.remove(&2, &1))
    {:reply, names, %{state | stopping: true}}
  end

  def handle_call({:attach_wire, name, device, fallback}, from, state) do
    case Wires.attach(state, name, device, fallback, from) do
      {:noreply, state} -> {:noreply, state}
      {:error, message} -> {:reply, {:error, message}, state}
    end
  end

  def handle_call({:detach_wire, name}, _from, state),
    do: {:reply, :ok, Wires.detach(state, name)}

  def handle_call({:subscribe, name, pid}, _from, state),
    do: {:reply, :ok, Activities.watch(state, name, pid)}

  def handle_call(:status, _from, state) do
    status =
      state.status
      |> Map.put(:restarts, state.restarts)
      |> Map.put(:statistics_dropped, Statistics.dropped())

    {:reply, status, state}
  end

  def handle_call(:wires, _from, state) do
    {:reply, Map.new(state.activities, fn {_, a} -> {a.name, Activities.wire(a)} end), state}
  end

  def handle_call(:os_pid, _from, state), do: {:reply, Worker.os_pid(state.port), state}

  @impl true
  def handle_info({port, {:data, frame}}, %{port: port} = state),
    do: {:noreply, handle_frame(Protocol.decode(frame), state)}

  def handle_info({port, :eof}, %{port: port} = state) do
    # with :eof the port outlives its program until closed
    Worker.close(port)
    {:noreply, restart(state, "closed its output (it died)")}
  end

  def handle_info({port, {:exit_status, status}}, %{port: port} = state) do
    Worker.close(port)
    {:noreply, restart(state, "exited with status #{status}")}
  end

  def handle_info({:EXIT, port, reason}, %{port: port} = state),
    do: {:noreply, restart(state, "port closed (#{inspect(reason)})")}

  def handle_info({:EXIT, pid, _reason}, %{statistics: pid} = state),
    do: {:noreply, start_statistics(state)}

  def handle_info({:EXIT, _other, _reason}, state), do: {:noreply, state}

  def handle_info({:DOWN, _ref, :process, pid, _reason}, state),
    do: {:noreply, Activities.down(state, pid, &Fallbacks.remove/2)}

  def handle_info(_other, state), do: {:noreply, state}

  @impl true
  def terminate(_reason, state) do
    if state.port, do: Port.close(state.port)
    Worker.forget()
    :ok
  catch
    _, _ -> :ok
  end

  ## Frames

  defp handle_frame({:release, id, cycle, scheduled, released, timer_late}, state),
    do: Releases.release(state, id, cycle, {scheduled, released, timer_late})

  defp handle_frame({:applied, id, frame}, state), do: Releases.applied(state, id, frame)

  defp handle_frame({:hello, status}, state) do
    Logger.info("timing worker: #{status.message}")
    %{state | status: status}
  end

  defp handle_frame({:wire_status, id, status, text}, state),
    do: Wires.status(state, id, status, text)

  defp handle_frame({:wire_error, rest}, state), do: Wires.error(state, rest)

  defp handle_frame({:error, text}, state) do
    Logger.error("timing worker refused a frame: #{text}")
    state
  end

  defp handle_frame({:unknown, other}, state) do
    Logger.error("unexpected frame from the timing worker: #{inspect(other, limit: 20)}")
    state
  end

  ## Statistics

  # the keeper of the statistics, with every activity held (anew after
  # it died)
  defp start_statistics(state) do
    pid =
      case Statistics.start_link(publish_every: state.publish_ms) do
        {:ok, pid} ->
          pid

        # a keeper left from a cycle that crashed, not yet gone
        {:error, {:already_started, pid}} ->
          Process.link(pid)
          pid
      end

    for {id, a} <- state.activities, do: Statistics.added(pid, id, a.name, a.period_ns)
    %{state | statistics: pid}
  end

  ## Worker

  defp open(state) do
    {port, status, boost} = Worker.open()
    %{state | port: port, status: status, boost: boost}
  end

  defp restart(state, why) do
    # the fallbacks first: the log may block when it is busy
    Fallbacks.worker_died(state)

    Logger.error("timing worker #{why}; restarting it, robot stopped until a fresh command")

    # a worker killed during a boost left the BEAM's threads boosted
    Worker.undo_boost(state.boost)
    state = open(%{state | port: nil, restarts: state.restarts + 1})

    # every activity again, with its wire; until its next fresh result, its
    # fallback holds (told above, before the new worker was spawned)
    for {id, a} <- state.activities do
      Worker.command(state.port, Protocol.add(a))
      if a.wire, do: Worker.command(state.port, Protocol.wire(id, a.wire))
    end

    Wires.resend_pending(state)
    state
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
