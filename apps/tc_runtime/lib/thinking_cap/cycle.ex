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
  `{:timing, name, summary}`.
  """
  use GenServer
  require Logger

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Cycle.Stats
  alias ThinkingCap.Runtime.Scheduling

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
          wired: boolean(),
          response_us: float(),
          applied_ns: integer() | nil
        }

  # the worker's limits on a wire's bytes and a device path
  @max_wire 4096
  @max_path 1023

  @kinds %{0 => :fresh, 1 => :fallback, 2 => :late}

  @doc "Starts the cycle and its timing worker (registered as `#{inspect(__MODULE__)}`)."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []), do: GenServer.start_link(__MODULE__, opts, name: __MODULE__)

  @doc """
  Adds a periodic activity: `period` and `deadline` in seconds, `priority`
  1..99 (releases due together go highest first), `fallback` (the command
  applied on a missed deadline, default `:stop`), `owner` (the process that
  gets the releases, default the caller).

  Adding a name again takes the activity over (a restarted module) unless
  another live process owns it: that is refused with the owner's pid.
  """
  @spec add(name(), keyword()) :: :ok | {:error, {:name_taken, pid()} | :stopping}
  def add(name, opts) do
    # checked here, in the caller: bad options raise there, never in the
    # server that holds every activity's releases
    period = seconds!(opts, :period)
    deadline = Keyword.get(opts, :deadline, period)
    priority = Keyword.get(opts, :priority, 50)

    unless is_number(deadline) and deadline > 0 and deadline <= period and priority in 1..99 do
      raise ArgumentError,
            "activity #{inspect(name)}: need 0 < deadline <= period and priority 1..99"
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
  Sends the result of a release (the command to apply) to the worker. Safe
  to call when the worker is down: the fallback is applied then anyway.
  """
  @spec result(release(), term()) :: :ok
  def result(%{id: id, cycle: cycle}, command),
    do: to_worker(<<?C, id::16, cycle::32, :erlang.term_to_binary(command)::binary>>)

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
        command = :erlang.term_to_binary(command)
        to_worker(<<?D, id::16, cycle::32, byte_size(wire)::16, wire::binary, command::binary>>)

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

  defp to_worker(frame) do
    case :persistent_term.get({__MODULE__, :port}, nil) do
      nil -> :ok
      port -> Port.command(port, frame)
    end

    :ok
  rescue
    ArgumentError -> :ok
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
      watchers: %{},
      # wire attachments waiting for the worker's answer, by activity id
      attaching: %{},
      stopping: false,
      # the threads the worker boosts while a result is pending
      boost: []
    }

    {:ok, open(state)}
  end

  @impl true
  def handle_call({:add, _name, _opts}, _from, %{stopping: true} = state),
    do: {:reply, {:error, :stopping}, state}

  def handle_call({:add, name, opts}, _from, state) do
    period = Keyword.fetch!(opts, :period)
    deadline = Keyword.get(opts, :deadline, period)
    priority = Keyword.get(opts, :priority, 50)
    fallback = Keyword.get(opts, :fallback, :stop)
    owner = Keyword.fetch!(opts, :owner)

    case live_owner(state, name) do
      other when is_pid(other) and other != owner ->
        {:reply, {:error, {:name_taken, other}}, state}

      _none_or_same ->
        add_activity(state, name, owner, period, deadline, priority, fallback)
    end
  end

  def handle_call({:remove, name}, _from, state), do: {:reply, :ok, remove_activity(state, name)}

  def handle_call(:stop_all, _from, state) do
    names = Map.keys(state.ids) |> Enum.filter(&Map.has_key?(state.activities, state.ids[&1]))
    state = Enum.reduce(names, state, &remove_activity(&2, &1))
    {:reply, names, %{state | stopping: true}}
  end

  def handle_call({:attach_wire, name, device, fallback}, from, state) do
    with {:ok, id} <- activity_id(state, name),
         {:ok, device} <- check_device(device),
         {:ok, fallback} <- check_fallback(fallback, device) do
      wire = %{device: device, fallback: fallback}
      send_wire(state.port, id, wire)
      attaching = Map.update(state.attaching, id, [{from, wire}], &(&1 ++ [{from, wire}]))
      {:noreply, %{state | attaching: attaching}}
    else
      {:error, message} -> {:reply, {:error, message}, state}
    end
  end

  def handle_call({:detach_wire, name}, _from, state) do
    case activity_id(state, name) do
      {:ok, id} ->
        if state.port, do: Port.command(state.port, <<?X, id::16>>)
        {:reply, :ok, put_in(state.activities[id].wire, nil)}

      {:error, _} ->
        {:reply, :ok, state}
    end
  end

  def handle_call({:subscribe, name, pid}, _from, state) do
    Process.monitor(pid)
    watchers = Map.update(state.watchers, name, MapSet.new([pid]), &MapSet.put(&1, pid))
    {:reply, :ok, %{state | watchers: watchers}}
  end

  def handle_call(:status, _from, state),
    do: {:reply, Map.put(state.status, :restarts, state.restarts), state}

  def handle_call(:timing, _from, state) do
    {:reply, Map.new(state.activities, fn {_, a} -> {a.name, summary(a)} end), state}
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
        do: Blackboard.out({:timing, a.name, summary(a)}, key: {:timing, a.name})

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

        a = %{a | stats: Stats.release(a.stats, scheduled, released), release: {cycle, released}}
        put_in(state.activities[id], a)

      _ ->
        state
    end
  end

  defp handle_frame(<<?P, id::16, cycle::32, kind, wired, response::64, command::binary>>, state)
       when is_map_key(@kinds, kind) do
    case state.activities do
      %{^id => a} ->
        kind = Map.fetch!(@kinds, kind)
        command = if command == "", do: nil, else: :erlang.binary_to_term(command)

        event = %{
          cycle: cycle,
          kind: kind,
          command: command,
          wired: wired == 1,
          response_us: response / 1000,
          applied_ns: applied_ns(a.release, cycle, kind, response)
        }

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

  defp handle_frame(<<?V, id::16, status, text::binary>>, state) do
    name = with %{name: name} <- state.activities[id], do: name

    case Map.get(state.attaching, id, []) do
      [{from, wire} | rest] when status in [0, 1] ->
        state = %{state | attaching: Map.put(state.attaching, id, rest)}

        cond do
          status == 0 ->
            GenServer.reply(from, {:error, text})
            state

          name == nil ->
            GenServer.reply(from, {:error, "#{wire.device}: the activity was removed"})
            state

          true ->
            GenServer.reply(from, :ok)
            put_in(state.activities[id].wire, wire)
        end

      _ ->
        wire_report(state, id, name, status, text)
    end
  end

  # a wire's error: "wire <id> <path>: ..."
  defp handle_frame(<<?E, "wire ", rest::binary>>, state) do
    with [id, _] <- String.split(rest, " ", parts: 2),
         {id, ""} <- Integer.parse(id),
         %{^id => a} <- state.activities do
      Logger.error("activity #{inspect(a.name)}: wire #{rest}")
      put_in(state.activities[id].wire_errors, a.wire_errors + 1)
    else
      _ ->
        Logger.error("timing worker: wire #{rest}")
        state
    end
  end

  defp handle_frame(<<?E, text::binary>>, state) do
    Logger.error("timing worker refused a frame: #{text}")
    state
  end

  defp handle_frame(other, state) do
    Logger.error("unexpected frame from the timing worker: #{inspect(other, limit: 20)}")
    state
  end

  # the worker reports a cycle's release before what it applied in it
  defp applied_ns({cycle, released}, cycle, kind, response) when kind != :late,
    do: released + response

  defp applied_ns(_release, _cycle, _kind, _response), do: nil

  ## Worker

  defp open(state) do
    path = Application.app_dir(:tc_runtime, "priv/bin/tc_timing")
    # :eof: the worker's output closing is the first sign of its death
    # (its exit status comes later, through the child-process helper)
    port = Port.open({:spawn_executable, path}, [:binary, {:packet, 4}, :exit_status, :eof])
    :persistent_term.put({__MODULE__, :port}, port)

    state =
      receive do
        {^port, {:data, <<?H, _::binary>> = hello}} -> handle_frame(hello, %{state | port: port})
      after
        5000 -> raise "the timing worker did not say hello within 5 s"
      end

    boost = Scheduling.release_boost()
    Port.command(port, [?B | for({tid, prio, _base} <- boost, do: <<tid::32, prio>>)])
    %{state | boost: boost}
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
        do:
          tell(state, a, %{
            cycle: 0,
            kind: :fallback,
            command: a.fallback,
            wired: false,
            response_us: 0.0,
            applied_ns: nil
          })

    # a worker killed during a boost left the BEAM's threads boosted
    Scheduling.undo_boost(state.boost)
    state = open(%{state | port: nil, restarts: state.restarts + 1})

    # every activity again, with its wire; until its next fresh result, its
    # fallback holds (told above, before the new worker was spawned)
    for {id, a} <- state.activities do
      send_add(state.port, a)
      if a.wire, do: send_wire(state.port, id, a.wire)
    end

    # attachments the dead worker did not answer: asked of the new one
    for {id, pending} <- state.attaching,
        {_from, wire} <- pending,
        do: send_wire(state.port, id, wire)

    state
  end

  # a wire's answer nobody waits for: re-attached after a restart, reopened
  defp wire_report(state, id, name, status, text) do
    case state.activities do
      %{^id => %{wire: wire}} when wire != nil and status == 0 ->
        Logger.error(
          "activity #{inspect(name)}: its wire could not be attached again: #{text}; " <>
            "its commands are not on the line until it is attached"
        )

        put_in(state.activities[id].wire, nil)

      %{^id => _} ->
        Logger.info("activity #{inspect(name)}: wire #{text}")
        state

      _ ->
        state
    end
  end

  defp summary(a) do
    a.stats
    |> Stats.summary()
    |> Map.merge(%{wire: a.wire && a.wire.device, wire_errors: a.wire_errors})
  end

  defp send_wire(port, id, %{device: device, fallback: fallback}) do
    Port.command(port, <<?W, id::16, byte_size(fallback)::16, fallback::binary, device::binary>>)
  end

  defp add_activity(state, name, owner, period, deadline, priority, fallback) do
    {id, state} = id_for(state, name)
    Process.monitor(owner)

    # added again: the worker keeps its wire, and so does this side
    old = Map.get(state.activities, id, %{})

    activity = %{
      id: id,
      name: name,
      period_ns: round(period * 1.0e9),
      deadline_ns: round(deadline * 1.0e9),
      priority: priority,
      fallback: fallback,
      owner: owner,
      wire: Map.get(old, :wire),
      wire_errors: Map.get(old, :wire_errors, 0),
      stats: Stats.new(round(period * 1.0e9)),
      # the last release: {cycle, released_ns}
      release: nil
    }

    send_add(state.port, activity)
    {:reply, :ok, put_in(state.activities[id], activity)}
  end

  # the live process that owns activity `name`, if any (a restarted
  # module's predecessor may be dead before its DOWN arrives here)
  defp live_owner(state, name) do
    with %{^name => id} <- state.ids,
         %{owner: pid} <- state.activities[id],
         true <- Process.alive?(pid) do
      pid
    else
      _ -> nil
    end
  end

  defp activity_id(state, name) do
    case state.ids do
      %{^name => id} when is_map_key(state.activities, id) -> {:ok, id}
      _ -> {:error, "no activity #{inspect(name)} to attach a wire to"}
    end
  end

  defp check_device(device) do
    device = if is_list(device), do: List.to_string(device), else: device

    cond do
      not is_binary(device) or device == "" ->
        {:error, "the wire's device must be a path, got #{inspect(device)}"}

      byte_size(device) > @max_path or String.contains?(device, <<0>>) ->
        {:error, "#{inspect(device)}: not a device path (too long, or a NUL byte in it)"}

      true ->
        {:ok, device}
    end
  rescue
    _ in [ArgumentError, UnicodeConversionError] ->
      {:error, "the wire's device must be a path, got #{inspect(device)}"}
  end

  defp check_fallback(fallback, device) do
    case IO.iodata_to_binary(fallback) do
      bytes when byte_size(bytes) <= @max_wire -> {:ok, bytes}
      bytes -> {:error, "#{device}: #{byte_size(bytes)} fallback bytes, over #{@max_wire}"}
    end
  rescue
    ArgumentError -> {:error, "#{device}: the fallback must be iodata, got #{inspect(fallback)}"}
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

        # what the worker does: the fallback bytes on the wire, if any
        tell(state, a, %{
          cycle: 0,
          kind: :fallback,
          command: a.fallback,
          wired: state.port != nil and a.wire != nil,
          response_us: 0.0,
          applied_ns: nil
        })

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
