defmodule ThinkingCap.Dashboard.Test.Rosbridge do
  @moduledoc """
  Helpers for rosbridge tests: a `ThinkingCap.Dashboard.Rosbridge.Session`
  run in the test process (its blackboard subscriptions are the test's),
  fed client messages and blackboard deliveries one by one, and made-up
  robots on the blackboard.
  """

  import ExUnit.Assertions

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Dashboard.Rosbridge.Session

  @token "rosbridge-test-token"

  @doc "The token sessions made by `open/1` accept."
  @spec token() :: String.t()
  def token, do: @token

  @doc """
  A session as a client connected (`control:` whether its URL had the
  token, `world:` the dashboard's world), opened.
  """
  @spec open(keyword()) :: map()
  def open(opts \\ []) do
    conn = %{
      control: Keyword.get(opts, :control, false),
      query: %{},
      peer: {{127, 0, 0, 1}, 40_000},
      origin: nil,
      config: %{token: @token, world: opts[:world]}
    }

    {:ok, state} = Session.init(conn)
    {_frames, state} = result(Session.handle_info(:open, state))
    state
  end

  @doc "Sends a client message (a map, encoded here, or raw text); returns the decoded replies."
  @spec send_msg(map(), map() | binary()) :: {[map()], map()} | {:close, map()}
  def send_msg(state, message) when is_map(message),
    do: send_msg(state, IO.iodata_to_binary(:jiffy.encode(message)))

  def send_msg(state, text) when is_binary(text),
    do: result(Session.handle_text(text, state))

  @doc """
  Hands the session the blackboard deliveries waiting for it, waiting up
  to `timeout` ms for the first frame `fun` accepts; returns every reply
  until then (flunks on timeout).
  """
  @spec deliver_until(map(), (map() -> boolean()), timeout()) :: {[map()], map()}
  def deliver_until(state, fun, timeout \\ 2_000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    do_deliver(state, fun, deadline, [])
  end

  defp do_deliver(state, fun, deadline, acc) do
    left = max(deadline - System.monotonic_time(:millisecond), 0)

    receive do
      {:blackboard, _, _} = message ->
        {frames, state} = result(Session.handle_info(message, state))
        acc = acc ++ frames

        if Enum.any?(frames, fun),
          do: {acc, state},
          else: do_deliver(state, fun, deadline, acc)
    after
      left -> flunk("no matching frame within the time; got #{inspect(acc, limit: 8)}")
    end
  end

  @doc "Hands the session every blackboard delivery already waiting; returns the replies."
  @spec deliver_waiting(map()) :: {[map()], map()}
  def deliver_waiting(state, acc \\ []) do
    receive do
      {:blackboard, _, _} = message ->
        {frames, state} = result(Session.handle_info(message, state))
        deliver_waiting(state, acc ++ frames)
    after
      50 -> {acc, state}
    end
  end

  @doc "A handler result as `{decoded frames, state}` (or `{:close, state}`)."
  @spec result(tuple()) :: {[map()], map()} | {:close, map()}
  def result({:reply, frames, state}),
    do:
      {Enum.map(frames, &:jiffy.decode(IO.iodata_to_binary(&1), [:return_maps, :use_nil])), state}

  def result({:noreply, state}), do: {[], state}
  def result({:close, state}), do: {:close, state}

  @doc """
  A made-up robot (a new name each time) that published its capabilities:
  a laser `:lidar` 0.1 m ahead and odometry `:odom`; limits 0.5 m/s,
  1 rad/s. Its tuples are taken off the blackboard when the test ends.
  """
  @spec robot!(keyword()) :: atom()
  def robot!(opts \\ []) do
    robot = :"rb#{System.unique_integer([:positive])}"

    caps = %{
      name: "test robot",
      footprint: [radius: 0.2],
      drive: :differential,
      limits: %{max_speed: 0.5, max_turn_rate: 1.0},
      sensors:
        Keyword.get(opts, :sensors, [
          %{name: :lidar, type: :laser, pose: {0.1, 0.0, 0.0}, range: {0.1, 8.0}},
          %{name: :odom, type: :odometry}
        ])
    }

    out({:robot, robot, caps})
    ExUnit.Callbacks.on_exit(fn -> clean(robot) end)
    robot
  end

  @doc "Writes a latest-value tuple (keyed by tag and robot)."
  @spec out(tuple()) :: :ok
  def out({tag, robot, _} = tuple), do: Blackboard.out(tuple, key: {tag, robot})

  defp clean(robot) do
    case Blackboard.takep({:_, robot, :_}) do
      {:ok, _} -> clean(robot)
      :none -> :ok
    end
  end

  @doc "The frames that publish on `topic`."
  @spec published([map()], String.t()) :: [map()]
  def published(frames, topic),
    do: for(%{"op" => "publish", "topic" => ^topic, "msg" => msg} <- frames, do: msg)

  @doc "The status frames of `level`."
  @spec statuses([map()], String.t()) :: [map()]
  def statuses(frames, level),
    do: for(%{"op" => "status", "level" => ^level} = f <- frames, do: f)
end
