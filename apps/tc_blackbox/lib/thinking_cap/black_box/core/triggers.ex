defmodule ThinkingCap.BlackBox.Core.Triggers do
  @moduledoc false
  # Which tuples are incidents worth a dump, for one robot: a pure value
  # that remembers what an edge needs (the E-stop, the bumpers, the
  # localization's status) and the deadline misses' streaks.
  alias ThinkingCap.Tuples
  require Tuples

  defstruct [
    :robot,
    activities: [],
    misses: 5,
    estop: false,
    pressed: %{},
    lost: false,
    fallbacks: %{},
    streaks: %{}
  ]

  @type t :: %__MODULE__{}

  @spec new(atom(), [atom()], pos_integer()) :: t()
  def new(robot, activities, misses),
    do: %__MODULE__{robot: robot, activities: activities, misses: misses}

  # The reason a tuple triggers a dump (or nil), and the state after it.
  @spec check(t(), tuple()) :: {String.t() | nil, t()}
  def check(%{robot: r} = s, Tuples.estop(r, %{engaged: engaged})) do
    reason = if engaged == true and not s.estop, do: "estop"
    {reason, %{s | estop: engaged == true}}
  end

  def check(%{robot: r} = s, Tuples.module_gave_up(r, _)), do: {"module_gave_up", s}

  def check(%{robot: r} = s, Tuples.black_box_request(r, %{reason: reason})),
    do: {text(reason), s}

  def check(%{robot: r} = s, Tuples.pose(r, payload)) when is_map(payload) do
    lost = Map.get(payload, :status) == :lost
    {if(lost and not s.lost, do: "localization_lost"), %{s | lost: lost}}
  end

  # a bumper's reading, whatever the sensor's name: %{pressed: boolean}
  def check(%{robot: r} = s, Tuples.reading(sensor, r, %{pressed: pressed})) do
    was = Map.get(s.pressed, sensor, false)
    reason = if pressed == true and not was, do: "bumper"
    {reason, %{s | pressed: Map.put(s.pressed, sensor, pressed == true)}}
  end

  def check(s, Tuples.timing(name, %{fallbacks: fallbacks}))
      when is_integer(fallbacks) do
    if name in s.activities, do: misses(s, name, fallbacks), else: {nil, s}
  end

  def check(s, _tuple), do: {nil, s}

  @spec text(term()) :: String.t()
  def text(reason) when is_binary(reason), do: reason
  def text(reason) when is_atom(reason), do: Atom.to_string(reason)
  def text(reason), do: inspect(reason)

  # the summaries are cumulative, once a second: a streak is a run of
  # summaries each with new misses; it triggers when it holds `misses`
  defp misses(s, name, fallbacks) do
    last = Map.get(s.fallbacks, name, 0)
    new = if fallbacks >= last, do: fallbacks - last, else: fallbacks
    streak = if new > 0, do: Map.get(s.streaks, name, 0) + new, else: 0
    s = %{s | fallbacks: Map.put(s.fallbacks, name, fallbacks)}

    if streak >= s.misses,
      do: {"deadline_misses", %{s | streaks: Map.put(s.streaks, name, 0)}},
      else: {nil, %{s | streaks: Map.put(s.streaks, name, streak)}}
  end
end
