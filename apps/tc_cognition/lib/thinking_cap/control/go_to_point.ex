defmodule ThinkingCap.Control.GoToPoint do
  @moduledoc """
  Drives to the goal: turns towards it, fast when it is far and ahead,
  slower near it, turning on the spot when it is well off to a side.

  Quantities: the goal's `distance` and `bearing` in the robot frame
  (bearing in (−π, π]: a goal exactly behind is at +π, so it is turned to
  on the left).

    * `bearing` - `:hard_right` (beyond −0.6 rad, fully from −1.2),
      `:right` (peak −0.4), `:ahead` (±0.25), `:left` (peak 0.4),
      `:hard_left` (beyond 0.6, fully from 1.2);
    * `distance` - `:at` (within `tolerance`, gone at twice that),
      `:near` (up to `slow_distance / 2`, gone at `slow_distance`),
      `:far` (beyond).

  Rules (`rules/0`): each bearing term turns the same way (`:ahead` →
  straight); hard turns stop; far and ahead → fast, far and off to a side
  → medium, near → slow, at → stop.

  Context: a goal is known and not reached (`1 - at(distance)`).

  `steer/4` is the same rule base for any target point, as used by
  `ThinkingCap.Control.FollowPath`.

  Params: `tolerance: 0.1` (m), `slow_distance: 1.0` (m).
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Fuzzy, Geometry}

  defstruct tolerance: 0.1, slow_distance: 1.0

  @type t :: %__MODULE__{}

  @impl true
  @spec init(keyword()) :: t()
  def init(params \\ []), do: struct!(__MODULE__, params)

  @impl true
  def context(%{goal: nil}, _p), do: 0.0

  def context(%{goal: goal, pose: pose}, p) do
    {distance, _} = Geometry.polar(Geometry.to_robot(pose, goal))
    reached(distance, p)
  end

  @impl true
  def outputs(%{goal: nil}, _p), do: %{}

  def outputs(%{goal: goal, pose: pose} = inputs, p) do
    {distance, bearing} = Geometry.polar(Geometry.to_robot(pose, goal))
    steer(distance, bearing, inputs, p)
  end

  @doc "`1 - at(distance)`: how far from reached a target at `distance` is."
  @spec reached(number(), t()) :: float()
  def reached(distance, p),
    do: 1.0 - Fuzzy.membership({:left_shoulder, p.tolerance, 2 * p.tolerance}, distance)

  @doc """
  The go-to rule base on a target at `distance` (m) and `bearing` (rad,
  robot frame).
  """
  @spec steer(number(), number(), Behaviour.inputs(), t()) :: Behaviour.outputs()
  def steer(distance, bearing, inputs, p) do
    Behaviour.control(rules(), %{distance: distance, bearing: bearing}, variables(p), inputs)
  end

  @doc "The rule base."
  @spec rules() :: Fuzzy.rule_base()
  def rules do
    hard = {:or, [{:is, :bearing, :hard_left}, {:is, :bearing, :hard_right}]}

    [
      [if: {:is, :bearing, :hard_left}, then: [w: :hard_left, v: :stop]],
      [if: {:is, :bearing, :left}, then: [w: :left]],
      [if: {:is, :bearing, :ahead}, then: [w: :straight]],
      [if: {:is, :bearing, :right}, then: [w: :right]],
      [if: {:is, :bearing, :hard_right}, then: [w: :hard_right, v: :stop]],
      [if: {:and, [{:is, :distance, :far}, {:is, :bearing, :ahead}]}, then: [v: :fast]],
      [
        if:
          {:and,
           [{:is, :distance, :far}, {:or, [{:is, :bearing, :left}, {:is, :bearing, :right}]}]},
        then: [v: :medium]
      ],
      [if: {:and, [{:is, :distance, :near}, {:not, hard}]}, then: [v: :slow]],
      [if: {:is, :distance, :at}, then: [v: :stop]]
    ]
  end

  @doc "The input variables for the parameters."
  @spec variables(t()) :: [Fuzzy.Variable.t()]
  def variables(p) do
    pi = :math.pi()
    tol = p.tolerance
    slow = max(p.slow_distance, 4 * tol)

    [
      Fuzzy.variable(:bearing, {-pi, pi},
        hard_right: {:left_shoulder, -1.2, -0.6},
        right: {:triangle, -0.9, -0.4, 0.0},
        ahead: {:triangle, -0.25, 0.0, 0.25},
        left: {:triangle, 0.0, 0.4, 0.9},
        hard_left: {:right_shoulder, 0.6, 1.2}
      ),
      Fuzzy.variable(:distance, {0.0, 1000.0},
        at: {:left_shoulder, tol, 2 * tol},
        near: {:trapezoid, tol, 2 * tol, slow / 2, slow},
        far: {:right_shoulder, slow / 2, slow}
      )
    ]
  end
end
