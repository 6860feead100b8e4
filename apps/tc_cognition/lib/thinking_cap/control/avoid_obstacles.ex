defmodule ThinkingCap.Control.AvoidObstacles do
  @moduledoc """
  Keeps the robot off obstacles: slows for an obstacle in its way and
  turns towards the freer side; steers away from obstacles close beside
  its front.

  Quantities (from the LPS, clearances measured from the robot's edge):

    * `ahead` - free distance along the corridor the robot sweeps driving
      straight (half-width `radius + margin`,
      `ThinkingCap.Control.Geometry.ahead/3`): `:blocked` below `stop`,
      `:near` up to `slow`, `:free` beyond;
    * `left` / `right` - clearance between 17° and 90° on each side:
      `:near` below 0.1 m fading out at 0.45 m.

  Rules (`rules/1`): blocked → stop and turn hard to the freer side; near →
  slow and turn to the freer side; free → medium speed, steer away from a
  near side, straight when both or neither side is near.

  **The freer side is a crisp choice**: the side whose clearance (from 0°
  to 70° on that side) is larger, and **ties break to the left**: the left
  is chosen unless the right is freer by more than `tie` (0.05 m). An
  obstacle further round, up to 110°, counts when it touches the robot
  (within `touch` of its edge): a door jamb at 73° touching the robot's
  left left the left side "free", and the robot turned into it. **A
  planned path decides first**: when the path's point 0.6 m ahead lies
  more than 0.3 rad off to one side and that side has 0.1 m of clearance,
  that side is chosen. A path through a gap beside a pillar otherwise had
  the robot go round the pillar by its freer, far side, away from the
  gap (`mix tc.bench nav`: path_ratio 1.10 before, 1.05 after, 20 of 20
  runs). A fuzzy
  "turn left or right" would defuzzify (centroid) to their average,
  straight into the obstacle; and once the robot turns left the obstacle
  moves to its right, so the choice holds (no dithering in a symmetric
  case). **A turn under way holds** while the way ahead is not free: with
  the last command turning at least `keep_turn` (0.5 rad/s), that side is
  kept. Walls all round (the end of a dead-end alley) do not move to one
  side as the robot turns; choosing afresh each cycle, an exploring robot
  turned left and right in a 0.7 m alley for 340 s, never round.

  Context: an obstacle is near in the direction of travel, the largest
  over the LPS's obstacle points ahead (x > 0) of
  `min(near(clearance), in_path(lateral offset))`, with `near` 1 up to
  `stop` and 0 from `near`, and `in_path` 1 up to `radius + margin` and 0
  from `radius + margin + 0.2`.

  Params: `stop: 0.15`, `slow: 0.45`, `near: 0.5` (m of clearance; tuned on
  `mix tc.bench nav`: wider margins keep a robot out of the gaps its
  planned path goes through),
  `margin: 0.02` (m: the corridor 2 cm wider than the robot on each
  side; with 0.05, on `mix tc.bench nav_unknown` the robot turned back
  at gaps among boxes its planned path went through, 0.6 to 0.7 m wide
  for a robot of 0.4), `tie: 0.05` (m), `keep_turn: 0.5` (rad/s), `touch: 0.03` (m).
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Fuzzy, Geometry}

  # clearance (m) a side needs for the path's side to be chosen
  @passable 0.1

  defstruct stop: 0.15,
            slow: 0.45,
            near: 0.5,
            margin: 0.02,
            tie: 0.05,
            keep_turn: 0.5,
            touch: 0.03

  @type t :: %__MODULE__{}

  @impl true
  @spec init(keyword()) :: t()
  def init(params \\ []), do: struct!(__MODULE__, params)

  @impl true
  def context(inputs, p) do
    r = inputs.radius
    near = {:left_shoulder, p.stop, p.near}
    in_path = {:left_shoulder, r + p.margin, r + p.margin + 0.2}

    inputs.lps
    |> Geometry.obstacles()
    |> Enum.reduce(0.0, fn {d, a}, acc ->
      x = d * :math.cos(a)
      y = d * :math.sin(a)

      if x > 0 do
        max(acc, min(Fuzzy.membership(near, d - r), Fuzzy.membership(in_path, abs(y))))
      else
        acc
      end
    end)
  end

  @impl true
  def outputs(inputs, p) do
    %{lps: lps, radius: r} = inputs
    side = freer_side(inputs, p)

    crisp = %{
      ahead: Geometry.ahead(lps, r, p.margin),
      left: Geometry.clearance(lps, 0.3, 1.571, r),
      right: Geometry.clearance(lps, -1.571, -0.3, r)
    }

    Behaviour.control(rules(side), crisp, variables(p, lps.range), inputs)
  end

  @doc """
  The side to turn to when something is in the way (see the moduledoc for
  ties and for a turn under way).
  """
  @spec freer_side(Behaviour.inputs(), t()) :: :left | :right
  def freer_side(%{lps: lps, radius: r} = inputs, p) do
    case turning(inputs, p) do
      nil ->
        left = side_clearance(lps, :left, r, p)
        right = side_clearance(lps, :right, r, p)

        case path_side(inputs) do
          :left when left >= @passable -> :left
          :right when right >= @passable -> :right
          _ -> if right > left + p.tie, do: :right, else: :left
        end

      side ->
        side
    end
  end

  # The clearance of a side, 0 to 70 degrees off the heading; and a side
  # the robot's edge touches further round, up to 110 degrees, is that
  # close. Beside a door jamb at 73 degrees on its left, touching it, the
  # robot saw its left side free and turned into the jamb (office, seed
  # 4).
  defp side_clearance(lps, :left, r, p),
    do: touching(Geometry.clearance(lps, 0.0, 1.22, r), Geometry.clearance(lps, 1.22, 1.92, r), p)

  defp side_clearance(lps, :right, r, p),
    do:
      touching(
        Geometry.clearance(lps, -1.22, 0.0, r),
        Geometry.clearance(lps, -1.92, -1.22, r),
        p
      )

  defp touching(front, beside, p), do: if(beside < p.touch, do: min(front, beside), else: front)

  # a planned path that turns off to one side (its lookahead point more
  # than 0.3 rad off the heading) says which side to go round by
  @path_lookahead 0.6

  defp path_side(%{path: [_ | _] = path, pose: {x, y, _} = pose}) do
    {point, _} = Geometry.lookahead(path, {x, y}, @path_lookahead)
    {_d, bearing} = Geometry.polar(Geometry.to_robot(pose, point))

    cond do
      bearing > 0.3 -> :left
      bearing < -0.3 -> :right
      true -> nil
    end
  end

  defp path_side(_inputs), do: nil

  # the side of a turn under way while the way ahead is not free
  defp turning(%{last: {_v, w}, lps: lps, radius: r}, p) when abs(w) >= p.keep_turn do
    if Geometry.ahead(lps, r, p.margin) < p.slow,
      do: if(w > 0, do: :left, else: :right)
  end

  defp turning(_inputs, _p), do: nil

  @doc "The rule base, turning to `side` when something is in the way."
  @spec rules(:left | :right) :: Fuzzy.rule_base()
  def rules(side) do
    {escape, dodge} = if side == :left, do: {:hard_left, :left}, else: {:hard_right, :right}

    [
      [if: {:is, :ahead, :blocked}, then: [v: :stop, w: escape]],
      [if: {:is, :ahead, :near}, then: [v: :slow, w: dodge]],
      [if: {:is, :ahead, :free}, then: [v: :medium]],
      [
        if: {:and, [{:is, :ahead, :free}, {:is, :left, :near}, {:not, {:is, :right, :near}}]},
        then: [w: :right]
      ],
      [
        if: {:and, [{:is, :ahead, :free}, {:is, :right, :near}, {:not, {:is, :left, :near}}]},
        then: [w: :left]
      ],
      [
        if:
          {:and,
           [
             {:is, :ahead, :free},
             {:or,
              [
                {:and, [{:is, :left, :near}, {:is, :right, :near}]},
                {:and, [{:not, {:is, :left, :near}}, {:not, {:is, :right, :near}}]}
              ]}
           ]},
        then: [w: :straight]
      ]
    ]
  end

  @doc "The input variables, for the parameters and the LPS's range."
  @spec variables(t(), number()) :: [Fuzzy.Variable.t()]
  def variables(p, range) do
    [
      Fuzzy.variable(:ahead, {0.0, range},
        blocked: {:left_shoulder, p.stop, 0.5 * (p.stop + p.slow)},
        near: {:triangle, p.stop, 0.5 * (p.stop + p.slow), p.slow},
        free: {:right_shoulder, 0.5 * (p.stop + p.slow), p.slow}
      ),
      Fuzzy.variable(:left, {0.0, range}, near: {:left_shoulder, 0.1, 0.45}),
      Fuzzy.variable(:right, {0.0, range}, near: {:left_shoulder, 0.1, 0.45})
    ]
  end
end
