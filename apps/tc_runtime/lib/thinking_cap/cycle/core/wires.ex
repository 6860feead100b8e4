defmodule ThinkingCap.Cycle.Core.Wires do
  @moduledoc false
  # Activities' wires for ThinkingCap.Cycle: a device's command path
  # handed to the worker. Attaching is checked here, then asked of the
  # worker, and answered when the worker says it opened the device (its
  # 'V' frame); the worker's later reports (reopened, errors) are logged
  # and counted. After a worker's restart every wire is attached again.
  require Logger

  alias ThinkingCap.Cycle.Core.{Activities, Protocol, Worker}

  # the worker's limits on a wire's bytes and a device path
  @max_bytes 4096
  @max_path 1023

  @doc "The most bytes a wire takes at once (a result's, or the fallback)."
  def max_bytes, do: @max_bytes

  @doc """
  Asks the worker to attach a wire; `{:noreply, state}` until it answers
  (the caller `from` waits), or `{:error, message}` at once.
  """
  def attach(state, name, device, fallback, from) do
    with {:ok, id} <- activity_id(state, name),
         {:ok, device} <- check_device(device),
         {:ok, fallback} <- check_fallback(fallback, device) do
      wire = %{device: device, fallback: fallback}
      Worker.command(state.port, Protocol.wire(id, wire))
      attaching = Map.update(state.attaching, id, [{from, wire}], &(&1 ++ [{from, wire}]))
      {:noreply, %{state | attaching: attaching}}
    end
  end

  @doc "Takes activity `name`'s wire from the worker."
  def detach(state, name) do
    case Activities.id_of(state, name) do
      {:ok, id} ->
        Worker.command(state.port, Protocol.detach(id))
        put_in(state.activities[id].wire, nil)

      :error ->
        state
    end
  end

  @doc "The attachments a dead worker did not answer, asked of the new one."
  def resend_pending(state) do
    for {id, pending} <- state.attaching,
        {_from, wire} <- pending,
        do: Worker.command(state.port, Protocol.wire(id, wire))

    :ok
  end

  @doc "The worker's word on a wire: the answer to an attachment, or a report."
  def status(state, id, status, text) do
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
        report(state, id, name, status, text)
    end
  end

  @doc "A wire's error: \"<id> <path>: ...\" (after \"wire \")."
  def error(state, rest) do
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

  # a wire's answer nobody waits for: re-attached after a restart, reopened
  defp report(state, id, name, status, text) do
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

  defp activity_id(state, name) do
    case Activities.id_of(state, name) do
      {:ok, id} -> {:ok, id}
      :error -> {:error, "no activity #{inspect(name)} to attach a wire to"}
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
      bytes when byte_size(bytes) <= @max_bytes -> {:ok, bytes}
      bytes -> {:error, "#{device}: #{byte_size(bytes)} fallback bytes, over #{@max_bytes}"}
    end
  rescue
    ArgumentError -> {:error, "#{device}: the fallback must be iodata, got #{inspect(fallback)}"}
  end
end
