defmodule ThinkingCap.Robot.Core.Base do
  @moduledoc false
  # The ThinkingCap.Module side of every `use ThinkingCap.Robot` driver:
  # loads the description, publishes readings, picks each cycle's command
  # and drives only what the timing worker applied.
  require Logger

  alias ThinkingCap.Robot
  alias ThinkingCap.Robot.Description

  @default_timeout 0.5

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
        state = %{
          driver: driver,
          dstate: dstate,
          robot: context.robot,
          description: description,
          timeout_ns: round(Keyword.get(params, :command_timeout, @default_timeout) * 1.0e9),
          command: :stop,
          received: nil,
          applied: nil
        }

        capabilities =
          {{:robot, context.robot, Robot.capabilities(description)},
           [key: {:robot, context.robot}]}

        {[out: capabilities, subscribe: {:drive, context.robot, :_}], state}

      {:error, reason} ->
        raise ArgumentError, "#{inspect(driver)} could not open the robot: #{inspect(reason)}"
    end
  end

  def handle_cycle(_release, state) do
    {readings, dstate} =
      if function_exported?(state.driver, :poll, 1),
        do: state.driver.poll(state.dstate),
        else: {[], state.dstate}

    command =
      if state.received && System.monotonic_time() - state.received <= state.timeout_ns,
        do: state.command,
        else: :stop

    {[{:command, command} | publish(readings, state.robot)], %{state | dstate: dstate}}
  end

  def handle_tuple({:drive, robot, %{command: command}}, %{robot: robot} = state) do
    case Robot.check_command(state.description, command) do
      :ok ->
        {[], %{state | command: command, received: System.monotonic_time()}}

      {:error, message} ->
        Logger.warning("#{inspect(robot)}: drive command refused: #{message}")
        {[], %{state | command: :stop, received: System.monotonic_time()}}
    end
  end

  def handle_tuple(_tuple, state), do: {[], state}

  # fresh or fallback, this is what the robot does now; a late result was
  # replaced by its fallback already
  def handle_applied(%{kind: :late}, state), do: {[], state}

  def handle_applied(%{command: command}, state) do
    command = command || :stop

    if command == state.applied,
      do: {[], state},
      else: {[], drive(command, state)}
  end

  def handle_info(message, state) do
    {readings, dstate} = state.driver.handle_data(message, state.dstate)
    {publish(readings, state.robot), %{state | dstate: dstate}}
  end

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
        do: {:out, {{sensor, robot, payload}, [key: {sensor, robot}]}}
  end

  defp load!(path) do
    case Description.load(path) do
      {:ok, description} -> description
      {:error, message} -> raise ArgumentError, message
    end
  end
end
