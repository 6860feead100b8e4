defmodule ThinkingCap.Control.BackOff do
  @moduledoc """
  The bumper reflex of `ThinkingCap.Control.Blender`: when a bumper
  closes while the robot drives forwards or turns, the robot backs off
  for `time` seconds at `speed`, turning its front away from the
  contact, and then the blend drives again.

  Without it a robot whose side met a door jamb stayed pressed there: the
  blend kept asking for a slow arc into the jamb, the move was refused at
  every step, and the planner's replans changed nothing (office patrol,
  seed 4: 739 blocked steps of 2,400, the task failed "no progress").

  The contact's side comes from the reading when it says so (`left:`,
  `right:`, as a Create 2 bumper does), else from the LPS: the side, left
  or right of the heading, with the nearer obstacle; with neither, it
  backs off straight. A contact on the left turns the robot clockwise as it backs off, swinging its front to
  the right.

  A new contact during the back-off (something behind) ends it: the
  robot does not push on. A car-like robot backs off along an arc its
  steering allows (`|w| <= speed * max_curvature`).

  This module holds the reflex's state; it is pure and the Blender
  calls it.
  """

  alias ThinkingCap.Control.Geometry
  alias ThinkingCap.Perception.LPS

  defstruct bumpers: [], time: 1.0, speed: 0.1, turn: 0.5, contact: nil, until: nil, w: 0.0

  @typedoc """
  `contact` is the side of a press not yet acted on (`:left`, `:right`,
  or `:unknown`); `until` the time the back-off under way ends, and `w`
  its turn rate.
  """
  @type t :: %__MODULE__{
          bumpers: [atom()],
          time: float(),
          speed: float(),
          turn: float(),
          contact: :left | :right | :unknown | nil,
          until: float() | nil,
          w: float()
        }

  # a forward speed (m/s) or turn rate (rad/s) below which the robot is
  # standing still: a press then is not of its making
  @moving 1.0e-3

  @doc """
  A reflex watching the sensors `bumpers`: `time` (s) and `speed` (m/s)
  of a back-off, `turn` its turn rate as a fraction of the top turn rate.
  """
  @spec new([atom()], keyword()) :: t()
  def new(bumpers, opts \\ []) do
    %__MODULE__{
      bumpers: bumpers,
      time: Keyword.get(opts, :time, 1.0) * 1.0,
      speed: Keyword.get(opts, :speed, 0.1) * 1.0,
      turn: Keyword.get(opts, :turn, 0.5) * 1.0
    }
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

  @doc "Whether a back-off is under way at `now` (s)."
  @spec active?(t(), number()) :: boolean()
  def active?(%__MODULE__{until: until}, now), do: until != nil and now < until

  @doc """
  The reflex's command at `now` (s): `{v, w}` while backing off, or `nil`
  when the blend drives. `last` is the command of the cycle before,
  `limits` the top speed and turn rate, `curvature` the tightest the
  steering allows (`:infinity` for a robot that turns on the spot).
  """
  @spec command(t(), number(), map()) :: {{float(), float()} | nil, t()}
  def command(%__MODULE__{} = reflex, now, %{last: {v, w}} = inputs) do
    contact = reflex.contact
    reflex = %{reflex | contact: nil}

    cond do
      active?(reflex, now) and contact != nil ->
        # pressed again while backing: something behind, stop pushing
        {nil, %{reflex | until: nil}}

      active?(reflex, now) ->
        {{-reflex.speed, reflex.w}, reflex}

      contact != nil and v > -@moving and (v > @moving or abs(w) > @moving) ->
        w = turn_away(reflex, contact, inputs)
        {{-reflex.speed, w}, %{reflex | until: now + reflex.time, w: w}}

      true ->
        {nil, %{reflex | until: nil}}
    end
  end

  defp turn_away(reflex, contact, inputs) do
    %{limits: %{max_turn_rate: wmax}, curvature: curvature} = inputs

    wmax =
      if curvature == :infinity,
        do: reflex.turn * wmax,
        else: min(reflex.turn * wmax, curvature * reflex.speed)

    case contact_side(contact, inputs) do
      :left -> -wmax
      :right -> wmax
      :unknown -> 0.0
    end
  end

  defp contact_side(:unknown, %{lps: %LPS{} = lps, radius: r}) do
    left = Geometry.clearance(lps, 0.0, 1.571, r)
    right = Geometry.clearance(lps, -1.571, 0.0, r)

    cond do
      right < left -> :right
      left < right -> :left
      true -> :unknown
    end
  end

  defp contact_side(:unknown, _inputs), do: :unknown
  defp contact_side(side, _inputs), do: side
end
