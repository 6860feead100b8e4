defmodule ThinkingCap.Robot.Core.Base do
  @moduledoc false
  # The ThinkingCap.Module side of every `use ThinkingCap.Robot` driver:
  # loads the description, publishes readings, picks each cycle's command
  # and drives only what the timing worker applied.
  require Logger

  alias ThinkingCap.Robot
  alias ThinkingCap.Robot.Description
  alias ThinkingCap.Tuples
  require Tuples

  @default_timeout 0.5
  @default_teleop_timeout 0.3

  def init(driver, params, context) do
    params = if is_map(params), do: Map.to_list(params), else: params || []

    description =
      case context[:rdf] do
        nil -> raise ArgumentError, "#{inspect(context.name)}: a robot needs the ADF's rdf:"
        path -> load!(path)
      end

    context = Map.put(context, :params, params)

    case driver.open(description, context) do
      {:ok, dstate} ->
        wire = wire(driver, dstate)

        state = %{
          driver: driver,
          dstate: dstate,
          robot: context.robot,
          description: description,
          timeout_ns: round(Keyword.get(params, :command_timeout, @default_timeout) * 1.0e9),
          teleop_timeout_ns:
            round(Keyword.get(params, :teleop_timeout, @default_teleop_timeout) * 1.0e9),
          command: :stop,
          received: nil,
          teleop: nil,
          estop: estop_latched?(context.robot),
          mode: :idle,
          applied: nil,
          published: nil,
          # the timing worker owns the command path: wire_command/2 every cycle
          wire: wire != nil
        }

        capabilities = Tuples.keyed(Tuples.robot(context.robot, Robot.capabilities(description)))

        attach = if wire, do: [{:attach_wire, elem(wire, 0), elem(wire, 1)}], else: []

        {[
           out: capabilities,
           subscribe: Tuples.drive(context.robot),
           subscribe: Tuples.teleop(context.robot),
           subscribe: Tuples.estop(context.robot)
         ] ++ attach, state}

      {:error, reason} ->
        raise ArgumentError, "#{inspect(driver)} could not open the robot: #{inspect(reason)}"
    end
  end

  # the driver's wire/1, once, after open/2
  defp wire(driver, dstate) do
    if function_exported?(driver, :wire, 1) do
      case driver.wire(dstate) do
        nil ->
          nil

        {device, fallback} ->
          unless function_exported?(driver, :wire_command, 2) do
            raise ArgumentError,
                  "#{inspect(driver)}: wire/1 names a device but there is no wire_command/2"
          end

          {device, fallback}

        other ->
          raise ArgumentError,
                "#{inspect(driver)}.wire/1 must return {device, fallback_iodata} or nil, " <>
                  "got #{inspect(other, limit: 5)}"
      end
    end
  end

  def handle_cycle(_release, state) do
    {readings, dstate} =
      if function_exported?(state.driver, :poll, 1),
        do: state.driver.poll(state.dstate),
        else: {[], state.dstate}

    {mode, command} = arbitrate(state, System.monotonic_time())

    wire = if state.wire, do: [wire: state.driver.wire_command(command, dstate)], else: []

    {[{:command, command} | wire] ++ publish(readings, state.robot),
     %{state | dstate: dstate, mode: mode}}
  end

  # Who drives this cycle: a latched E-stop stops the robot; a fresh
  # teleoperation command (refreshed within teleop_timeout: the deadman
  # rule) overrides autonomy; then the autonomous command while fresh;
  # otherwise the robot stops.
  defp arbitrate(state, now) do
    cond do
      state.estop ->
        {:estop, :stop}

      state.teleop != nil and now - state.teleop.received <= state.teleop_timeout_ns ->
        {:teleop, state.teleop.command}

      state.received != nil and now - state.received <= state.timeout_ns ->
        {:autonomy, state.command}

      true ->
        {:idle, :stop}
    end
  end

  def handle_tuple(Tuples.drive(robot, %{command: command}), %{robot: robot} = state) do
    case Robot.check_command(state.description, command) do
      :ok ->
        {[], %{state | command: command, received: System.monotonic_time()}}

      {:error, message} ->
        Logger.warning("#{inspect(robot)}: drive command refused: #{message}")
        {[], %{state | command: :stop, received: System.monotonic_time()}}
    end
  end

  def handle_tuple(Tuples.teleop(robot, %{command: :release}), %{robot: robot} = state),
    do: {[], %{state | teleop: nil}}

  def handle_tuple(Tuples.teleop(robot, %{command: command} = teleop), %{robot: robot} = state) do
    case Robot.check_command(state.description, command) do
      :ok ->
        teleop = %{
          command: command,
          received: System.monotonic_time(),
          sent_at: teleop[:sent_at],
          by: teleop[:by]
        }

        {[], %{state | teleop: teleop}}

      {:error, message} ->
        Logger.warning("#{inspect(robot)}: teleoperation command refused: #{message}")
        {[], %{state | teleop: nil}}
    end
  end

  def handle_tuple(Tuples.estop(robot, %{engaged: engaged}), %{robot: robot} = state)
      when is_boolean(engaged),
      do: {[], %{state | estop: engaged}}

  def handle_tuple(_tuple, state), do: {[], state}

  # fresh or fallback, this is what the robot does now; a late result was
  # replaced by its fallback already
  def handle_applied(%{kind: :late}, state), do: {[], state}

  # the timing worker put it on the line already: not driven again
  def handle_applied(%{command: command, wired: true}, state),
    do: announce(%{state | applied: command || :stop})

  def handle_applied(%{command: command}, state) do
    command = command || :stop
    state = if command == state.applied, do: state, else: drive(command, state)
    announce(state)
  end

  # `{:control, robot, %{mode, command, ...}}` whenever who drives or what
  # is driven changes: the dashboard shows it, and a teleoperation
  # command's `sent_at` comes back in it (key press to applied latency)
  defp announce(%{mode: mode, applied: applied} = state) do
    if {mode, applied} == state.published do
      {[], state}
    else
      control = %{
        mode: mode,
        command: applied,
        teleop_by: if(mode == :teleop, do: state.teleop[:by]),
        teleop_sent_at: if(mode == :teleop, do: state.teleop[:sent_at])
      }

      {[out: Tuples.keyed(Tuples.control(state.robot, control))],
       %{state | published: {mode, applied}}}
    end
  end

  defp estop_latched?(robot) do
    match?(
      {:ok, Tuples.estop(_, %{engaged: true})},
      ThinkingCap.Blackboard.rdp(Tuples.estop(robot))
    )
  end

  def handle_info(message, state) do
    {readings, dstate} = state.driver.handle_data(message, state.dstate)
    {reattach(state, dstate) ++ publish(readings, state.robot), %{state | dstate: dstate}}
  end

  # A driver that reopened its line (a new device behind the same path)
  # names it again: the worker, which reopens only the device it first
  # opened, is handed the new one.
  defp reattach(%{wire: true} = state, dstate) do
    case {wire(state.driver, state.dstate), wire(state.driver, dstate)} do
      {nil, {device, fallback}} -> [{:attach_wire, device, fallback}]
      _ -> []
    end
  end

  defp reattach(_state, _dstate), do: []

  def terminate(reason, state) do
    # leave the robot stopped whatever happened
    {_, _, dstate} = apply_command(:stop, state)
    state.driver.close(reason, dstate)
  end

  defp drive(command, state) do
    case apply_command(command, state) do
      {:ok, _, dstate} ->
        %{state | dstate: dstate, applied: command}

      {:error, reason, dstate} ->
        Logger.warning(
          "#{inspect(state.robot)}: #{inspect(command)} failed: #{inspect(reason)}; stopping"
        )

        {_, _, dstate} = apply_command(:stop, %{state | dstate: dstate})
        %{state | dstate: dstate, applied: :stop}
    end
  end

  defp apply_command(command, state) do
    case state.driver.drive(command, state.dstate) do
      {:ok, dstate} -> {:ok, nil, dstate}
      {:error, reason, dstate} -> {:error, reason, dstate}
    end
  end

  defp publish(readings, robot) do
    for {sensor, payload} <- readings,
        do: {:out, Tuples.keyed(Tuples.reading(sensor, robot, payload))}
  end

  defp load!(path) do
    case Description.load(path) do
      {:ok, description} -> description
      {:error, message} -> raise ArgumentError, message
    end
  end
end
