defmodule ThinkingCap.Runtime.Scheduling do
  @moduledoc """
  How the OS schedules the BEAM's own threads, so that the control
  activity gets the CPU under load.

  The timing worker is a separate thread at `SCHED_FIFO` priority 80: its
  releases and fallbacks never wait for the BEAM. But a fresh command has
  to be computed by the BEAM, whose threads otherwise compete with every
  process on the machine. So at start the runtime puts the BEAM's normal
  scheduler threads at **`SCHED_FIFO` priority 1** and its I/O poller
  (through which the worker's frames arrive) at 2; its dirty CPU
  schedulers join the normal ones at 1:

    * they preempt ordinary (`SCHED_OTHER`) processes, so OS-level load
      cannot delay a control cycle;
    * priority 1 is the lowest real-time priority: the timing worker (80),
      serial drivers and the kernel's own real-time threads still preempt
      the BEAM;
    * the kernel's real-time throttling (`sched_rt_runtime_us`, 95 % by
      default) keeps a BEAM that is busy for long from starving the rest of
      the machine entirely;
    * schedulers should not busy-wait at real-time priority: run the VM with
      `+sbwt none +sbwtdcpu none +sbwtdio none` (`bin/run` does; the runtime
      logs a warning when busy-waiting is on);
    * the I/O poller, through which port data arrives, runs one priority
      above the schedulers (2): threads of one `SCHED_FIFO` priority never
      preempt each other, and at the schedulers' own priority the poller
      waited for a scheduler to run out of work: measured, a port's round
      trip took up to 420 ms while two Erlang processes kept both
      schedulers busy, and the control cycle missed most deadlines in a
      tuple flood;
    * the dirty CPU schedulers run at the schedulers' priority, because
      they collect the garbage of large processes: OTP moves a collection
      of 128K words or more (`ERTS_POTENTIALLY_LONG_GC_HSIZE`) to them,
      and the process waits meanwhile. At normal priority such a thread
      runs only while no real-time thread wants its core. In `mix
      tc.bench record` (100 robots, 60 s) collections of
      `ThinkingCap.Cycle`, through which every release passes, took up
      to 104 ms, and the control cycles missed 12 to 53 deadlines (78 to
      124 while recording); at the schedulers' priority the longest took
      19 to 43 ms, and the control cycles missed none but in a stall of
      the machine itself (the cycle now keeps its statistics in another
      process, so its own heap stays small). Once running, a dirty
      thread is not preempted by a scheduler of its own priority; under
      full load it waits until a scheduler runs out of work, and its CPU
      counts toward the kernel's real-time throttling;
    * the dirty I/O schedulers (file I/O) stay at normal priority.

  Measured with `mix tc.bench timing` (100 Hz, deadline 3 ms, two CPU hogs,
  30 s): at nice −10 the module's cycle time varied by 4.4 % of the period
  and 0.5 % of cycles missed their deadline; at `SCHED_FIFO` 1, 0.4 % and
  0.03 %.

  ## The release boost

  At `SCHED_FIFO` 1 the BEAM is still one real-time program among others:
  threads of the same priority never preempt each other, so another
  program's busy thread at priority 1 or 2 kept a periodic module from its
  release for up to 800 ms (`mix tc.bench timing` beside other BEAMs at
  `SCHED_FIFO` 1). So while a periodic activity's result is pending
  (released, neither its result in nor its fallback applied), the timing
  worker holds the schedulers (normal and dirty CPU) at **`SCHED_FIFO`
  20** and the poller at 21,
  and puts them back as it found them when no result is pending
  (`release_boost/0` names the threads; the worker does the rest):

    * the module's release and its work go before other programs' low
      real-time threads, the BEAM's background work (which shares the
      schedulers) only within those windows;
    * the windows end at the activities' deadlines at the latest: a
      module stuck in its cycle gets its fallback and the boost ends;
    * 20 stays below the kernel's interrupt threads (50) and the timing
      worker (80).

  Measured with `mix tc.bench timing` (the paper's two 150 ms activities,
  three event and one background activity, while other agents' BEAMs ran
  at `SCHED_FIFO` 1): without the boost the activities' releases reached
  `handle_cycle/2` up to 91 and 811 ms late; with it, see the README.

  ## What no priority helps

  A scheduler thread that collects a process's garbage is not preempted
  by the BEAM, and a periodic module queued on that scheduler waits for it.
  Measured in the fault suite's tuple flood: a writer that kept its
  100,000 results in a list had a heap whose collection took 3 to 7 ms,
  and the 3 ms deadline was missed (the fallback applied). Processes on a
  robot's node should not grow heaps of many megabytes; keep big data in
  ETS or binaries.

  The `:tc_runtime, :periodic_priority` setting is the boost's scheduler
  priority (20; the poller one above); `nil` turns it off. There is no
  boost unless the schedulers run at real-time priority.

  The `:tc_runtime, :beam_priority` setting chooses: `:realtime` (the
  default; falls back to nice −10 where real-time priority is refused),
  `{:nice, n}`, or `nil` to leave the BEAM as it is. Both need root or
  `CAP_SYS_NICE`; without them the runtime logs that and carries on.
  """
  require Logger

  # the thread names: 15 characters at most, so "12_dirty_cpu_sc"
  @threads ~r/^\d+_(scheduler|poller|dirty_cpu_s\w*)$/

  @typedoc "How one thread is scheduled."
  @type thread_policy :: %{
          policy: :other | :fifo | :rr | :batch | :idle,
          rt_priority: non_neg_integer(),
          nice: integer()
        }

  @doc """
  Puts the BEAM's scheduler threads (normal and dirty CPU) at
  `SCHED_FIFO` `priority`, and its I/O poller thread one above: threads of
  one `SCHED_FIFO` priority never preempt each other, so a poller at the
  schedulers' priority waits, on a machine with as many cores as
  schedulers, until a scheduler runs out of work; port data (the timing
  worker's releases) then waits with it, for hundreds of milliseconds
  under load.
  """
  @spec realtime(1..98) :: {:ok, [String.t()]} | {:error, String.t()}
  def realtime(priority \\ 1) do
    each_thread(fn tid ->
      prio = if String.ends_with?(comm(tid), "_poller"), do: priority + 1, else: priority
      System.cmd("chrt", ["-f", "-p", "#{prio}", tid], stderr_to_stdout: true)
    end)
  end

  @typedoc "A thread the timing worker boosts: its id, its boost priority and its own."
  @type boost :: {tid :: pos_integer(), boost :: 1..98, base :: 1..98}

  @doc """
  The threads the timing worker boosts while a periodic result is
  pending: each scheduler (normal and dirty CPU) at `:periodic_priority`
  (default 20), the poller one above, with the `SCHED_FIFO` priority
  each has now. `[]` when the boost is off or the schedulers do not run
  at real-time priority below their boost.
  """
  @spec release_boost() :: [boost()]
  def release_boost do
    with priority when is_integer(priority) <- periodic_priority(),
         policies = for(tid <- threads(), do: {tid, safe_policy(tid)}),
         true <- policies != [] and Enum.all?(policies, &below_boost?(&1, priority)) do
      for {tid, %{rt_priority: base}} <- policies do
        prio = if String.ends_with?(comm(tid), "_poller"), do: priority + 1, else: priority
        {String.to_integer(tid), prio, base}
      end
    else
      _ -> []
    end
  end

  defp below_boost?({_tid, %{policy: :fifo, rt_priority: p}}, priority), do: p < priority
  defp below_boost?(_thread, _priority), do: false

  @doc """
  Puts back threads a timing worker left boosted (it was killed during a
  boost): each thread still at its boost priority goes back to its own.
  Threads someone else rescheduled are left alone.
  """
  @spec undo_boost([boost()]) :: :ok
  def undo_boost(boost) do
    for {tid, prio, base} <- boost,
        match?(%{policy: :fifo, rt_priority: ^prio}, safe_policy("#{tid}")),
        do: System.cmd("chrt", ["-f", "-p", "#{base}", "#{tid}"], stderr_to_stdout: true)

    :ok
  rescue
    ErlangError -> :ok
  end

  @doc "The scheduler priority of the release boost (`:periodic_priority`), or nil when it is off."
  @spec periodic_priority() :: 2..97 | nil
  def periodic_priority do
    case Application.get_env(:tc_runtime, :periodic_priority, 20) do
      nil ->
        nil

      p when is_integer(p) and p in 2..97 ->
        p

      other ->
        raise ArgumentError,
              ":tc_runtime, :periodic_priority must be 2..97 or nil, got #{inspect(other)}"
    end
  end

  @doc """
  Sets the nice value of the BEAM's scheduler (normal and dirty CPU) and
  poller threads (back to `SCHED_OTHER`).
  """
  @spec nice(integer()) :: {:ok, [String.t()]} | {:error, String.t()}
  def nice(value) do
    each_thread(fn tid ->
      with {_, 0} <- System.cmd("chrt", ["-o", "-p", "0", tid], stderr_to_stdout: true),
           do: System.cmd("renice", ["-n", "#{value}", "-p", tid], stderr_to_stdout: true)
    end)
  end

  @doc """
  How each of the BEAM's scheduler (normal and dirty CPU) and poller
  threads is scheduled, by thread name.
  """
  @spec policies() :: %{String.t() => thread_policy()}
  def policies do
    for tid <- threads(), into: %{}, do: {comm(tid), thread_policy(tid)}
  end

  defp thread_policy(tid) do
    stat = File.read!("/proc/#{System.pid()}/task/#{tid}/stat")
    # the fields after the ")" closing the thread name start at field 3
    fields = stat |> String.split(") ", parts: 2) |> List.last() |> String.split(" ")
    field = fn n -> fields |> Enum.at(n - 3) |> String.to_integer() end

    policy =
      Map.get(%{0 => :other, 1 => :fifo, 2 => :rr, 3 => :batch, 5 => :idle}, field.(41), :other)

    %{policy: policy, rt_priority: field.(40), nice: field.(19)}
  end

  # a thread may end between the listing and the reading
  defp safe_policy(tid) do
    thread_policy(tid)
  rescue
    File.Error -> nil
  end

  @doc "True when the VM was started with scheduler busy-waiting off (`+sbwt none`)."
  @spec busy_wait_off?() :: boolean()
  def busy_wait_off? do
    args = "/proc/#{System.pid()}/cmdline" |> File.read!() |> String.split(<<0>>)
    args |> Enum.chunk_every(2, 1, :discard) |> Enum.member?(["-sbwt", "none"])
  rescue
    File.Error -> false
  end

  @doc false
  # Applies the :beam_priority setting (called when the runtime starts).
  @spec apply_config() :: :ok
  def apply_config do
    case Application.get_env(:tc_runtime, :beam_priority, :realtime) do
      nil ->
        :ok

      :realtime ->
        case realtime(1) do
          {:ok, tids} ->
            Logger.info(
              "BEAM scheduler threads (normal and dirty CPU) at SCHED_FIFO 1, poller at 2 (#{length(tids)} threads)"
            )

            unless busy_wait_off?() do
              Logger.warning(
                "schedulers busy-wait at real-time priority: start the VM with +sbwt none +sbwtdcpu none +sbwtdio none"
              )
            end

          {:error, reason} ->
            Logger.warning("real-time priority refused (#{reason}); trying nice -10")
            apply_nice(-10)
        end

      {:nice, value} ->
        apply_nice(value)
    end

    :ok
  end

  defp apply_nice(value) do
    case nice(value) do
      {:ok, _} ->
        Logger.info("BEAM scheduler and poller threads at nice #{value}")

      {:error, reason} ->
        Logger.warning("could not set the BEAM's scheduler threads to nice #{value}: #{reason}")
    end
  end

  defp each_thread(fun) do
    case threads() do
      [] ->
        {:error, "no scheduler threads found under /proc/#{System.pid()}/task"}

      tids ->
        Enum.reduce_while(tids, {:ok, tids}, fn tid, ok ->
          case fun.(tid) do
            {_, 0} -> {:cont, ok}
            {output, _} -> {:halt, {:error, String.trim(output)}}
          end
        end)
    end
  rescue
    e in ErlangError -> {:error, "chrt/renice unavailable: #{Exception.message(e)}"}
  end

  defp threads do
    for dir <- Path.wildcard("/proc/#{System.pid()}/task/*"),
        tid = Path.basename(dir),
        Regex.match?(@threads, comm(tid)),
        do: tid
  end

  defp comm(tid) do
    case File.read("/proc/#{System.pid()}/task/#{tid}/comm") do
      {:ok, name} -> String.trim(name)
      {:error, _} -> ""
    end
  end
end
