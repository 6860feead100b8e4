defmodule ThinkingCap.Runtime.Starting do
  @moduledoc """
  Services that must be ready before an ADF's modules start. A recorder
  must: it records every module's inputs from its `init/2` on, so that the
  module can be replayed (`ThinkingCap.Runtime.Trace`). The runtime does
  not depend on the apps above it; such a service's process calls
  `listen/0` on its node instead, and `ThinkingCap.Runtime.start/1` tells
  it of each ADF before it starts the first module, then waits for its
  answer (at most #{5_000} ms for all of them):

      Starting.listen()

      def handle_info({:tc_adf_starting, _ref, _from, robot, adf} = starting, state) do
        # ... start what adf[:record] asks for robot ...
        Starting.ready(starting)
        {:noreply, state}
      end

  `adf` is the payload of the ADF's announcement (`ThinkingCap.Runtime.start/1`).
  """

  @group :tc_adf_starting
  @timeout 5_000

  @typedoc "What a listener is sent."
  @type message :: {:tc_adf_starting, reference(), pid(), atom(), map()}

  @doc "The calling process hears of every ADF this node starts, before its modules start."
  @spec listen() :: :ok
  def listen, do: :pg.join(ThinkingCap.Runtime.scope(), @group, self())

  @doc "Answers the runtime: the listener is ready for the ADF's modules."
  @spec ready(message()) :: :ok
  def ready({:tc_adf_starting, ref, from, _robot, _adf}) do
    send(from, {:tc_adf_ready, ref, self()})
    :ok
  end

  @doc false
  # Tells this node's listeners of `robot`'s ADF and waits for their answers.
  @spec notify(atom(), map()) :: :ok
  def notify(robot, adf) do
    ref = make_ref()
    listeners = :pg.get_local_members(ThinkingCap.Runtime.scope(), @group)
    for pid <- listeners, do: send(pid, {:tc_adf_starting, ref, self(), robot, adf})
    deadline = System.monotonic_time(:millisecond) + @timeout
    await(ref, listeners, deadline)
  end

  defp await(_ref, [], _deadline), do: :ok

  defp await(ref, waiting, deadline) do
    left = max(deadline - System.monotonic_time(:millisecond), 0)

    receive do
      {:tc_adf_ready, ^ref, pid} -> await(ref, List.delete(waiting, pid), deadline)
    after
      left -> :ok
    end
  end
end
