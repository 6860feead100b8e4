defmodule ThinkingCap.Dashboard.Core.RestartLimit do
  @moduledoc false
  # How often clients may restart modules, all clients together: one
  # module at most once every @per_module_ms, and at most @per_minute
  # restarts a minute in all: a restart stops a module and its fallback
  # holds until it is back, so no client, however many sockets it opens,
  # may keep a robot's modules restarting. (Restarts asked for do not
  # count against a layer's restart intensity: ThinkingCap.Runtime.Supervision.)

  use Agent

  @per_module_ms 5_000
  @per_minute 20

  @doc false
  def start_link(_), do: Agent.start_link(fn -> %{last: %{}, recent: []} end, name: __MODULE__)

  @doc """
  Asks to restart `module` (any term naming it) at `now_ms` (monotonic):
  `:ok` (counted), or `{:error, sentence}` saying when it may be asked again.
  """
  @spec admit(term(), integer()) :: :ok | {:error, String.t()}
  def admit(module, now_ms \\ System.monotonic_time(:millisecond)) do
    Agent.get_and_update(__MODULE__, fn state ->
      recent = Enum.filter(state.recent, &(now_ms - &1 < 60_000))
      last = Map.get(state.last, module)

      cond do
        last != nil and now_ms - last < @per_module_ms ->
          wait = ceil((@per_module_ms - (now_ms - last)) / 1000)

          {{:error,
            "restarted less than #{div(@per_module_ms, 1000)} s ago: try again in #{wait} s"},
           %{state | recent: recent}}

        length(recent) >= @per_minute ->
          {{:error, "#{@per_minute} restarts in the last minute: try again later"},
           %{state | recent: recent}}

        true ->
          {:ok, %{last: Map.put(state.last, module, now_ms), recent: [now_ms | recent]}}
      end
    end)
  end
end
