defmodule ThinkingCap.Control.BackOff do
  @moduledoc """
  The bumper reflex of `ThinkingCap.Control.Blender`: when a bumper
  closes while the robot drives forwards or turns, the robot backs off
  straight for `time` seconds at `speed`, turns on the spot by `angle`
  away from the contact, and then the blend drives again.

  Without it a robot whose side met a door jamb stayed pressed there: the
  blend kept asking for a slow arc into the jamb, the move was refused at
  every step, and the planner's replans changed nothing (office patrol,
  seed 4: 739 blocked steps of 2,400, the task failed "no progress").

  The contact's side comes from the reading when it says so (`left:`,
  `right:`, as a Create 2 bumper does), else from the LPS: the side, left
  or right of the heading, with the nearer obstacle; with neither, it
  only backs off. A contact on the left turns the robot clockwise.
  Backing off straight first matters: a robot backing along a clockwise
  arc from a wall on its left swings its rear into the wall, and its
  centre towards it.

  The planner may ask for the same back-off (`recoveries/2`): a robot
  found making no progress backs off before it follows its new plan,
  bumper or not, the side from the LPS.

  A new contact during the back-off (something behind) ends it: the
  robot does not push on. A car-like robot cannot turn on the spot: it
  backs off along an arc its steering allows (`|w| <= speed *
  max_curvature`) that swings its front away.

  This module holds the reflex's state; it is pure and the Blender
  calls it.
  """

  alias ThinkingCap.Control.Geometry
  alias ThinkingCap.Perception.LPS

  defstruct bumpers: [],
            time: 1.0,
            speed: 0.1,
            angle: 0.5,
            turn: 0.5,
            contact: nil,
            steps: [],
            recoveries: nil,
            requested: false

  @typedoc """
  `contact` is the side of a press not yet acted on (`:left`, `:right`,
  or `:unknown`); `steps` the back-off under way, each command with the
  time it ends; `recoveries` the planner's count of recoveries last seen
  (nil before its first plan), `requested` a recovery not yet acted on.
  """
  @type t :: %__MODULE__{
          bumpers: [atom()],
          time: float(),
          speed: float(),
          angle: float(),
          turn: float(),
          contact: :left | :right | :unknown | nil,
          steps: [{float(), {float(), float()}}],
          recoveries: non_neg_integer() | nil,
          requested: boolean()
        }

  # a forward speed (m/s) or turn rate (rad/s) below which the robot is
  # standing still: a press then is not of its making
  @moving 1.0e-3

  @doc """
  A reflex watching the sensors `bumpers`: `time` (s, default 1.0) and
  `speed` (m/s, 0.1) of the straight back-off, `angle` (rad, 0.5) of the
  turn after it, `turn` (0.5) the turn rate as a fraction of the top
  turn rate; `max_speed` (m/s) caps `speed`. An option given as nil
  keeps its default.
  """
  @spec new([atom()], keyword()) :: t()
  def new(bumpers, opts \\ []) do
    given =
      for {key, value} <- opts,
          key in [:time, :speed, :angle, :turn],
          is_number(value),
          into: %{},
          do: {key, value * 1.0}

    reflex = Map.merge(%__MODULE__{bumpers: bumpers}, given)

    case Keyword.get(opts, :max_speed) do
      max when is_number(max) -> %{reflex | speed: min(reflex.speed, max * 1.0)}
      _ -> reflex
    end
  end

  @doc "Whether `sensor` is one of the bumpers watched."
  @spec bumper?(t(), atom()) :: boolean()
  def bumper?(%__MODULE__{bumpers: bumpers}, sensor), do: sensor in bumpers

  @doc "Takes a bumper's reading: a press is remembered until the next cycle acts on it."
  @spec reading(t(), map()) :: t()
  def reading(%__MODULE__{} = reflex, %{pressed: true} = payload),
    do: %{reflex | contact: side(payload)}

  def reading(%__MODULE__{} = reflex, _payload), do: reflex

  defp side(%{left: true, right: false}), do: :left
  defp side(%{left: false, right: true}), do: :right
  defp side(_payload), do: :unknown

  @doc """
  Takes the planner's count of recoveries (`ThinkingCap.Planner.Monitor`:
  the times it found the robot making no progress): a count above the
  last one seen asks for a back-off, whatever the robot is doing. The
  first count seen asks for nothing: it may be old.
  """
  @spec recoveries(t(), non_neg_integer()) :: t()
  def recoveries(%__MODULE__{recoveries: nil} = reflex, n), do: %{reflex | recoveries: n}

  def recoveries(%__MODULE__{recoveries: seen} = reflex, n) when n > seen,
    do: %{reflex | recoveries: n, requested: true}

  def recoveries(%__MODULE__{} = reflex, _n), do: reflex

  @doc """
  Forgets a back-off under way and a press or a request not acted on:
  for a robot the plan stops. The recoveries count seen is kept.
  """
  @spec reset(t()) :: t()
  def reset(%__MODULE__{} = reflex), do: %{reflex | steps: [], contact: nil, requested: false}

  @doc "Whether a back-off is under way at `now` (s)."
  @spec active?(t(), number()) :: boolean()
  def active?(%__MODULE__{steps: steps}, now),
    do: Enum.any?(steps, fn {until, _} -> now < until end)

  @doc """
  The reflex's command at `now` (s): `{v, w}` while backing off, or `nil`
  when the blend drives. `inputs` are the blend's, with `last` (the
  command of the cycle before) and `curvature` (the tightest the
  steering allows, `:infinity` for a robot that turns on the spot).
  """
  @spec command(t(), number(), map()) :: {{float(), float()} | nil, t()}
  def command(%__MODULE__{} = reflex, now, %{last: {v, w}} = inputs) do
    %{contact: contact, requested: requested} = reflex
    reflex = %{reflex | contact: nil, requested: false}

    cond do
      active?(reflex, now) and contact != nil ->
        # pressed again while backing off: something behind, stop pushing
        {nil, %{reflex | steps: []}}

      active?(reflex, now) ->
        steps = Enum.drop_while(reflex.steps, fn {until, _} -> now >= until end)
        [{_, command} | _] = steps
        {command, %{reflex | steps: steps}}

      requested or (contact != nil and v > -@moving and (v > @moving or abs(w) > @moving)) ->
        steps = steps(reflex, now, contact_side(contact || :unknown, inputs), inputs)
        command(%{reflex | steps: steps}, now, inputs)

      true ->
        {nil, %{reflex | steps: []}}
    end
  end

  # straight back, then on the spot away from the contact; a car-like
  # robot backs along an arc swinging its front away
  defp steps(reflex, now, side, %{limits: %{max_turn_rate: wmax}, curvature: :infinity}) do
    back = {now + reflex.time, {-reflex.speed, 0.0}}
    rate = reflex.turn * wmax

    case away(side) do
      sign when sign != 0.0 and rate > 0 ->
        [back, {now + reflex.time + reflex.angle / rate, {0.0, sign * rate}}]

      _ ->
        [back]
    end
  end

  defp steps(reflex, now, side, %{limits: %{max_turn_rate: wmax}, curvature: k}) do
    rate = min(reflex.turn * wmax, k * reflex.speed)
    [{now + reflex.time, {-reflex.speed, away(side) * rate}}]
  end

  # the sign of the turn that swings the front away from the contact
  defp away(:left), do: -1.0
  defp away(:right), do: 1.0
  defp away(:unknown), do: 0.0

  defp contact_side(:unknown, %{lps: %LPS{} = lps, radius: r}) do
    left = Geometry.clearance(lps, 0.0, 1.571, r)
    right = Geometry.clearance(lps, -1.571, 0.0, r)

    cond do
      right < left -> :right
      left < right -> :left
      true -> :unknown
    end
  end

  defp contact_side(side, _inputs), do: side
end
