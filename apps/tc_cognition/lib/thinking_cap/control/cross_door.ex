defmodule ThinkingCap.Control.CrossDoor do
  @moduledoc """
  Crosses the plan's door: lines up with the door's axis (the line through
  its centre along its heading) and drives along it through the centre.

  The target is the point of the axis `lookahead` metres (or half the
  distance to the door, if more) past the robot's own projection on it
  (pure pursuit on the axis), so the robot joins the axis smoothly and
  passes the centre aligned with the heading. When the
  LPS sees a door (`lps.doors`, robot frame) within `match` metres of the
  plan's, the perceived door is used (position, heading, width): it is
  where the robot actually sees the opening.

  Quantities: the target's `bearing` (the terms of
  `ThinkingCap.Control.GoToPoint`) and the robot's `offset` from the axis,
  as a fraction of the room it has: in the door `width / 2 - radius`,
  and before it that widened by `funnel` times the distance still to go
  (a robot 1.5 m before a door need not yet be on its axis to the
  centimetre, and should not crawl there): `:centred` below 0.2, `:off`
  from 0.6.

  Rules (`rules/0`): the bearing turns as in go-to; ahead and centred →
  medium speed; ahead and off → slow; left or right → slow; hard → stop.

  Context: a door to cross is near and ahead: the minimum of "the robot
  fits" (width from `2 radius`, fully at `2 radius + 0.1`), "near" (centre
  within `approach`, fully within 60% of it), "not yet through" (the
  robot's centre up to `radius` past the door, gone at `radius + beyond`)
  and "ahead" (the centre within ±1.2 rad of the heading, gone at ±1.8,
  or the robot within 0.5 m of the centre and facing the heading).

  A door given without a `heading` is crossed in the direction from the
  robot to its centre.

  Params: `lookahead: 0.5`, `approach: 2.5`, `beyond: 0.3`, `match: 0.4`
  (m), `funnel: 0.5`.
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Fuzzy, Geometry, GoToPoint}
  alias ThinkingCap.Perception.LPS
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  defstruct lookahead: 0.5, approach: 2.5, beyond: 0.3, match: 0.4, funnel: 0.5

  @type t :: %__MODULE__{}

  @impl true
  @spec init(keyword()) :: t()
  def init(params \\ []), do: struct!(__MODULE__, params)

  @impl true
  def context(inputs, p), do: inputs |> door(p) |> applies(inputs.radius, p)

  @impl true
  def outputs(inputs, p) do
    case door(inputs, p) do
      nil -> %{}
      door -> steer(door, inputs, p)
    end
  end

  @impl true
  def evaluate(inputs, p) do
    case door(inputs, p) do
      nil -> {0.0, %{}}
      door -> {applies(door, inputs.radius, p), steer(door, inputs, p)}
    end
  end

  @doc """
  The door in the robot frame: `%{centre: {x, y}, heading: rad, width: m,
  along: s, lateral: e}` with `along` the robot's coordinate along the
  axis (negative before the door) and `lateral` its offset from it; `nil`
  without a door.
  """
  @spec door(Behaviour.inputs(), t()) :: map() | nil
  def door(%{door: nil}, _p), do: nil

  def door(%{door: %{centre: centre, width: width} = given} = inputs, p) do
    {_, _, theta} = inputs.pose
    {cx, cy} = local = Geometry.to_robot(inputs.pose, centre)

    heading =
      case given do
        %{heading: heading} when is_number(heading) -> normalize_angle(heading - theta)
        _ -> :math.atan2(cy, cx)
      end

    planned = %{centre: local, heading: heading, width: width}

    %{centre: {cx, cy}, heading: phi} = door = perceived(inputs.lps, planned, p) || planned
    {ux, uy} = {:math.cos(phi), :math.sin(phi)}
    Map.merge(door, %{along: -(cx * ux + cy * uy), lateral: -ux * cy + uy * cx})
  end

  defp perceived(%LPS{doors: doors}, %{centre: {px, py}, heading: phi}, p) do
    doors
    |> Enum.map(fn %{centre: {x, y}} = d -> {:math.sqrt((x - px) ** 2 + (y - py) ** 2), d} end)
    |> Enum.filter(fn {dist, _} -> dist <= p.match end)
    |> Enum.min_by(fn {dist, _} -> dist end, fn -> nil end)
    |> case do
      nil ->
        nil

      {_, d} ->
        # the same crossing direction as the plan's
        h =
          if abs(normalize_angle(d.heading - phi)) > :math.pi() / 2,
            do: normalize_angle(d.heading + :math.pi()),
            else: normalize_angle(d.heading)

        %{centre: d.centre, heading: h, width: d.width}
    end
  end

  defp applies(nil, _radius, _p), do: 0.0

  defp applies(door, radius, p) do
    {distance, bearing} = Geometry.polar(door.centre)
    fits = Fuzzy.membership({:right_shoulder, 2 * radius, 2 * radius + 0.1}, door.width)
    near = Fuzzy.membership({:left_shoulder, 0.6 * p.approach, p.approach}, distance)
    not_through = Fuzzy.membership({:left_shoulder, radius, radius + p.beyond}, door.along)
    facing = fn angle -> Fuzzy.membership({:left_shoulder, 1.2, 1.8}, abs(angle)) end
    close = Fuzzy.membership({:left_shoulder, 0.5, 0.8}, distance)
    ahead = max(facing.(bearing), min(close, facing.(door.heading)))
    Enum.min([fits, near, not_through, ahead])
  end

  defp steer(door, inputs, p) do
    %{centre: {cx, cy}, heading: phi, along: s, lateral: e} = door
    t = s + max(p.lookahead, -s / 2)
    {_, bearing} = Geometry.polar({cx + t * :math.cos(phi), cy + t * :math.sin(phi)})
    to_go = max(-s - inputs.radius, 0.0)
    room = max(door.width / 2 - inputs.radius, 0.01) + p.funnel * to_go
    crisp = %{bearing: bearing, offset: abs(e) / room}
    Behaviour.control(rules(), crisp, variables(), inputs)
  end

  @doc "The rule base."
  @spec rules() :: Fuzzy.rule_base()
  def rules do
    [
      [if: {:is, :bearing, :hard_left}, then: [w: :hard_left, v: :stop]],
      [if: {:is, :bearing, :left}, then: [w: :left, v: :slow]],
      [if: {:is, :bearing, :ahead}, then: [w: :straight]],
      [if: {:is, :bearing, :right}, then: [w: :right, v: :slow]],
      [if: {:is, :bearing, :hard_right}, then: [w: :hard_right, v: :stop]],
      [if: {:and, [{:is, :bearing, :ahead}, {:is, :offset, :centred}]}, then: [v: :medium]],
      [if: {:and, [{:is, :bearing, :ahead}, {:is, :offset, :off}]}, then: [v: :slow]]
    ]
  end

  @doc "The input variables."
  @spec variables() :: [Fuzzy.Variable.t()]
  def variables do
    [bearing | _] = GoToPoint.variables(GoToPoint.init())

    [
      bearing,
      Fuzzy.variable(:offset, {0.0, 10.0},
        centred: {:left_shoulder, 0.2, 0.6},
        off: {:right_shoulder, 0.2, 0.6}
      )
    ]
  end
end
