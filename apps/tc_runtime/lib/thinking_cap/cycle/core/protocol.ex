defmodule ThinkingCap.Cycle.Core.Protocol do
  @moduledoc false
  # The frames between the BEAM and the timing worker, as binaries (the
  # PROTOCOL comment of c_src/tc_timing.c; integers big-endian). Pure:
  # encoding what the BEAM tells the worker, decoding what it answers.

  @kinds %{0 => :fresh, 1 => :fallback, 2 => :late}

  @doc """
  'A': adds (or adds again) an activity. The worker releases it `lead_ns`
  early, so its deadline runs that much longer from the release.
  """
  def add(a) do
    fallback = :erlang.term_to_binary(a.fallback)
    deadline = a.deadline_ns + a.lead_ns
    <<?A, a.id::16, a.period_ns::64, deadline::64, a.priority, fallback::binary>>
  end

  @doc "'R': removes an activity (the worker applies its fallback)."
  def remove(id), do: <<?R, id::16>>

  @doc "'C': a release's result."
  def result(id, cycle, command),
    do: <<?C, id::16, cycle::32, :erlang.term_to_binary(command)::binary>>

  @doc "'D': a release's result with the bytes for its wire."
  def wired_result(id, cycle, wire, command) do
    command = :erlang.term_to_binary(command)
    <<?D, id::16, cycle::32, byte_size(wire)::16, wire::binary, command::binary>>
  end

  @doc "'W': attaches a wire (its device and fallback bytes)."
  def wire(id, %{device: device, fallback: fallback}),
    do: <<?W, id::16, byte_size(fallback)::16, fallback::binary, device::binary>>

  @doc "'X': detaches a wire."
  def detach(id), do: <<?X, id::16>>

  @doc "'B': the threads to boost while a result is pending, `{tid, priority, _base}`."
  def boost(threads),
    do: IO.iodata_to_binary([?B | for({tid, prio, _base} <- threads, do: <<tid::32, prio>>)])

  @doc """
  A frame from the worker: `{:release, id, cycle, scheduled_ns, released_ns,
  timer_late_ns}`,
  `{:applied, id, event}` (its command still encoded: `command/1`),
  `{:hello, status}`, `{:wire_status, id, status, text}`,
  `{:wire_error, text}` (after "wire "), `{:error, text}` or `{:unknown, frame}`.
  """
  def decode(<<?L, id::16, cycle::32, scheduled::64, released::64, timer_late::32>>),
    do: {:release, id, cycle, scheduled, released, timer_late}

  def decode(<<?P, id::16, cycle::32, kind, wired, response::64, command::binary>>)
      when is_map_key(@kinds, kind) do
    {:applied, id,
     %{
       cycle: cycle,
       kind: Map.fetch!(@kinds, kind),
       command: command,
       wired: wired == 1,
       response_ns: response
     }}
  end

  def decode(<<?H, fifo, mlock, text::binary>>),
    do: {:hello, %{sched_fifo: fifo == 1, mlockall: mlock == 1, message: text}}

  def decode(<<?V, id::16, status, text::binary>>), do: {:wire_status, id, status, text}
  def decode(<<?E, "wire ", rest::binary>>), do: {:wire_error, rest}
  def decode(<<?E, text::binary>>), do: {:error, text}
  def decode(other), do: {:unknown, other}

  @doc "An applied frame's command: nil when the worker sent none (a late result)."
  def command(""), do: nil
  def command(binary), do: :erlang.binary_to_term(binary)
end
