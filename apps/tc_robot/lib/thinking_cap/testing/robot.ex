defmodule ThinkingCap.Testing.Robot do
  @moduledoc """
  A test robot: a `ThinkingCap.Robot` driver without hardware, for testing
  modules that drive a robot (and the robot framework itself). Put it in
  an ADF where the real driver would be:

      base: [module: ThinkingCap.Testing.Robot, activity: :periodic, period: 0.01,
             deadline: 0.005, fallback: :stop]

  Every command it is driven with is published as
  `{:driven, robot, %{command: command, count: n}}` (latest value), so a
  test reads what the robot was told to do from the blackboard; `feed/2`
  hands it readings as if they had come from the hardware, and they are
  published like a real robot's. Param `refuse: [command kinds]` makes it
  answer `{:error, :refused}` to those kinds (`:velocity`, `:wheels`, ...)
  to test what happens when hardware refuses a command.

  Param `wire: path` hands the command path to the timing worker (see
  `ThinkingCap.Robot`): the test robot opens no line itself; the worker
  writes each applied command to `path` as `"\#{inspect(command)}\\n"`
  (`:stop` as `"stop\\n"`) and `"stop\\n"` whenever it applies the
  fallback, so a test reads the line (a pty made with
  `ThinkingCap.Robot.UART.open_pty/2`). Commands the worker put on the
  line do not reach `drive/2`: they are not published as `:driven`.
  """
  use ThinkingCap.Robot

  alias ThinkingCap.Runtime
  alias ThinkingCap.Tuples
  require Tuples

  @doc "Hands the test robot hosted as module `name` (or at `pid`) some readings."
  @spec feed(atom() | pid(), [ThinkingCap.Robot.reading()]) :: :ok
  def feed(name, readings) when is_atom(name), do: feed(Runtime.whereis(name), readings)

  def feed(pid, readings) when is_pid(pid),
    do: send(pid, {:tc_test_robot, :feed, readings}) && :ok

  @impl true
  def open(description, context) do
    {:ok,
     %{
       robot: context.robot,
       description: description,
       refuse: Keyword.get(context.params, :refuse, []),
       wire: Keyword.get(context.params, :wire),
       count: 0
     }}
  end

  @impl true
  def wire(%{wire: nil}), do: nil
  def wire(%{wire: path}), do: {path, "stop\n"}

  @impl true
  def wire_command(:stop, _state), do: "stop\n"
  def wire_command(command, _state), do: "#{inspect(command)}\n"

  @impl true
  def drive(command, state) do
    kind = if is_tuple(command), do: elem(command, 0), else: command

    if kind in state.refuse do
      {:error, :refused, state}
    else
      count = state.count + 1
      {driven, opts} = Tuples.keyed(Tuples.driven(state.robot, %{command: command, count: count}))
      :ok = ThinkingCap.Blackboard.out(driven, opts)
      {:ok, %{state | count: count}}
    end
  end

  @impl true
  def handle_data({:tc_test_robot, :feed, readings}, state), do: {readings, state}
  def handle_data(_message, state), do: {[], state}

  @impl true
  def close(_reason, _state), do: :ok
end
