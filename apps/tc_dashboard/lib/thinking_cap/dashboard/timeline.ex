defmodule ThinkingCap.Dashboard.Timeline do
  @max 4
  @idle_ms 600_000

  @moduledoc """
  The black box's last minute, for scrubbing in the dashboard: one
  process per open timeline holds a snapshot of a robot's black box
  (`ThinkingCap.BlackBox.snapshot/2`) taken when it opened, so what the
  page scrubs does not move under its slider, and answers frames: what
  the map showed at an instant.

      {:ok, pid, summary} = Timeline.open(:r1, self())
      {:ok, json} = Timeline.frame(pid, summary.to - 10_000, nil)

  It keeps only what the map draws: the poses (`:pose`, `:sim_pose`,
  `:odom`), the laser scans (the sensors of type `:laser` in the robot's
  capabilities, else `:laser`), the plan, the learned map and the
  capabilities. A stream that sent nothing during the snapshot's span
  (a map that did not change) has the value it has on the blackboard
  (read just before the snapshot: it held all along).

  What goes to the browser is bounded: one instant per frame, asked for
  by time, and the map (the largest payload, shrunk as the live one is)
  only when it is not the one the page already has. At most
  #{@max} timelines are open on a node (each holds its snapshot in memory);
  one closes with the process that opened it, with `close/1`, or after
  #{div(@idle_ms, 60_000)} minutes without a frame.
  """
  use GenServer

  alias ThinkingCap.{BlackBox, Blackboard}
  alias ThinkingCap.Dashboard.Core.{JSON, Payload, Scrub}
  alias ThinkingCap.Tuples
  require Tuples

  @supervisor ThinkingCap.Dashboard.Timelines
  @streams [
    Tuples.tag(:pose),
    Tuples.tag(:sim_pose),
    :odom,
    Tuples.tag(:plan),
    Tuples.tag(:map),
    Tuples.tag(:robot)
  ]

  @typedoc """
  What `open/2` answers: the span (`from`, `to`, ms since the epoch), the
  tuples held per stream (`"tag/robot"` => count), the incidents in the
  span (what made the black box dump: `at`, ms since the epoch, and
  `reason`, oldest first), those the black box dropped for its bounds
  since it started.
  """
  @type summary :: %{
          robot: atom(),
          from: integer(),
          to: integer(),
          streams: %{String.t() => non_neg_integer()},
          incidents: [%{at: integer(), reason: String.t()}],
          dropped: non_neg_integer()
        }

  @doc false
  # the DynamicSupervisor's bound
  @spec max_open() :: pos_integer()
  def max_open, do: @max

  @doc """
  Opens a timeline of `robot`'s black box for `owner` (it closes when
  `owner` exits). Refused with a message when the robot has no black box
  on this node, or when #{@max} timelines are open.
  """
  @spec open(atom(), pid()) :: {:ok, pid(), summary()} | {:error, String.t()}
  def open(robot, owner \\ self()) when is_atom(robot) and is_pid(owner) do
    start =
      if BlackBox.ring_buffer(robot),
        do: DynamicSupervisor.start_child(@supervisor, {__MODULE__, {robot, owner}}),
        else: :ignore

    case start do
      {:ok, pid} ->
        {:ok, pid, GenServer.call(pid, :summary)}

      {:error, :max_children} ->
        {:error, "#{@max} timelines are open on this node, the most it keeps: close one first"}

      # no black box, or it stopped while the snapshot was asked for
      :ignore ->
        {:error, ThinkingCap.Dashboard.Dumps.no_black_box(robot)}

      {:error, reason} ->
        {:error, "the timeline of #{robot} could not open: #{inspect(reason)}"}
    end
  end

  @doc """
  The frame at `at_ms` (ms since the epoch, taken into the span) as the
  page's JSON object body: `"at"`, `"map"` (which map it shows, an
  integer, or null) and `"items"` (`"tag/robot"` => payload or null).
  The map's payload is left out when it is `have_map`, the one the page
  has.
  """
  @spec frame(pid(), number(), integer() | nil) :: {:ok, binary()} | {:error, String.t()}
  def frame(pid, at_ms, have_map) when is_number(at_ms) do
    {:ok, GenServer.call(pid, {:frame, at_ms, have_map}, 10_000)}
  catch
    :exit, _ -> {:error, "the timeline is closed: open it again"}
  end

  @doc "Closes a timeline."
  @spec close(pid()) :: :ok
  def close(pid) do
    _ = DynamicSupervisor.terminate_child(@supervisor, pid)
    :ok
  end

  @doc false
  def child_spec({robot, owner}),
    do: %{
      id: __MODULE__,
      start: {__MODULE__, :start_link, [{robot, owner}]},
      restart: :temporary
    }

  @doc false
  def start_link(arg), do: GenServer.start_link(__MODULE__, arg)

  ## Server

  @impl true
  def init({robot, owner}) do
    Process.monitor(owner)
    tags = @streams ++ lasers(robot)
    # read before the snapshot: a stream with nothing in its span held
    # this value all along
    seeds = seeds(robot, tags)

    case BlackBox.snapshot(robot, tags: tags) do
      {:ok, snapshot} ->
        # an incident's ms rounded up: the frame at it holds the tuples
        # that came with it, in the same millisecond
        incidents =
          for %{at: t, reason: reason} <- Map.get(snapshot, :incidents, []),
              do: %{at: div(t + 999_999, 1_000_000), reason: reason}

        {:ok, %{scrub: Scrub.new(snapshot, seeds), incidents: incidents}, @idle_ms}

      {:error, :not_keeping} ->
        :ignore
    end
  catch
    # the black box stopped during the call
    :exit, _ -> :ignore
  end

  @impl true
  def handle_call(:summary, _from, %{scrub: scrub} = state) do
    summary = %{
      robot: scrub.robot,
      from: div(scrub.from, 1_000_000),
      to: div(scrub.to, 1_000_000),
      streams: Map.new(Scrub.counts(scrub), fn {tag, n} -> {key(tag, scrub.robot), n} end),
      incidents: state.incidents,
      dropped: scrub.dropped
    }

    {:reply, summary, state, @idle_ms}
  end

  def handle_call({:frame, at_ms, have_map}, _from, %{scrub: scrub} = state) do
    t = at_ms |> ns() |> max(scrub.from) |> min(scrub.to)
    picks = Scrub.at(scrub, t)

    map =
      case picks[:map] do
        {:seed, _} -> -1
        {i, _} -> i
        nil -> nil
      end

    items =
      for {tag, pick} <- picks,
          not (tag == :map and map != nil and map == have_map) do
        key = key(tag, scrub.robot)
        json = if pick, do: Payload.encode(key, elem(pick, 1)), else: "null"
        [JSON.encode!(key), ?:, json]
      end

    body = [
      ~s("at":),
      Integer.to_string(div(t, 1_000_000)),
      ~s(,"map":),
      if(map, do: Integer.to_string(map), else: "null"),
      ~s(,"items":{),
      Enum.intersperse(items, ?,),
      "}"
    ]

    {:reply, IO.iodata_to_binary(body), state, @idle_ms}
  end

  @impl true
  def handle_info({:DOWN, _ref, :process, _owner, _reason}, state), do: {:stop, :normal, state}
  def handle_info(:timeout, state), do: {:stop, :normal, state}
  def handle_info(_other, state), do: {:noreply, state, @idle_ms}

  # ms since the epoch in ns, exactly: a float of today's ns has lost
  # its last digits (beyond 2^53)
  defp ns(ms) when is_integer(ms), do: ms * 1_000_000

  defp ns(ms) when is_float(ms) do
    whole = trunc(ms)
    whole * 1_000_000 + round((ms - whole) * 1.0e6)
  end

  # the robot's laser sensors, from its capabilities
  defp lasers(robot) do
    case Blackboard.rdp(Tuples.robot(robot)) do
      {:ok, Tuples.robot(^robot, %{sensors: sensors})} when is_list(sensors) ->
        for %{name: name, type: :laser} <- sensors, is_atom(name), do: name

      _ ->
        []
    end
    |> case do
      [] -> [:laser]
      names -> names
    end
  end

  defp seeds(robot, tags) do
    for tag <- tags, {:ok, {_, _, payload}} <- [Blackboard.rdp({tag, robot, :_})], into: %{} do
      {tag, payload}
    end
  end

  defp key(tag, robot), do: "#{tag}/#{robot}"
end
