defmodule ThinkingCap.Control.FollowWall do
  @moduledoc """
  Follows a wall on one side at a set distance (from the robot's centre
  to the wall), turning away from a wall ahead (an inner corner).

  Quantities (`ThinkingCap.Control.Geometry.wall/2`, from the LPS's
  segments or its nearest points on that side):

    * `error` - wall distance minus `distance`: `:too_close` (from
      −0.15 m), `:ok` (±0.1 m), `:too_far` (to +0.15 m);
    * `approach` - angle between heading and wall, positive towards it:
      `:towards` (0.05 → 0.35 rad), `:parallel` (±0.15), `:away`;
    * `front` - free distance ahead in the robot's own width (`Geometry.ahead/3`,
      no margin: the wall followed is not in the way): `:blocked`
      below 0.3 m, gone at 0.6 m.

  Rules (`rules/0`, written for a wall on the left and mirrored for the
  right): too close and not heading away → turn away; too far and not
  heading towards it → turn towards it; at the distance, turn to run
  parallel; blocked ahead → slow and turn hard away from the wall; else
  medium speed.

  Context: a wall is seen on that side within `distance + 0.2` m (fading
  out at `distance + 0.5`).

  Params: `side: :left | :right | :nearest` (default `:nearest`: the side
  whose wall is nearer, ties to the left), `distance: 0.5` (m).
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Fuzzy, Geometry}

  defstruct side: :nearest, distance: 0.5

  @type t :: %__MODULE__{side: :left | :right | :nearest, distance: float()}

  @impl true
  @spec init(keyword()) :: t()
  def init(params \\ []) do
    p = struct!(__MODULE__, params)

    unless p.side in [:left, :right, :nearest] do
      raise ArgumentError,
            "FollowWall side: expected :left, :right or :nearest, got #{inspect(p.side)}"
    end

    p
  end

  @impl true
  def context(inputs, p) do
    case wall(inputs.lps, p.side) do
      nil -> 0.0
      {_side, {d, _approach}} -> presence(d, p)
    end
  end

  @impl true
  def outputs(inputs, p) do
    case wall(inputs.lps, p.side) do
      nil ->
        %{}

      {side, {d, approach}} ->
        crisp = %{
          error: d - p.distance,
          approach: approach,
          front: Geometry.ahead(inputs.lps, inputs.radius, 0.0)
        }

        rules = if side == :left, do: rules(), else: Behaviour.mirror(rules())
        Behaviour.control(rules, crisp, variables(inputs.lps.range), inputs)
    end
  end

  defp presence(d, p),
    do: Fuzzy.membership({:left_shoulder, p.distance + 0.2, p.distance + 0.5}, d)

  @doc "The wall followed: its side and `{distance, approach}`, or `nil`."
  @spec wall(ThinkingCap.Perception.LPS.t(), :left | :right | :nearest) ::
          {:left | :right, {float(), float()}} | nil
  def wall(lps, :nearest) do
    case {Geometry.wall(lps, :left), Geometry.wall(lps, :right)} do
      {nil, nil} -> nil
      {left, nil} -> {:left, left}
      {nil, right} -> {:right, right}
      {{dl, _} = left, {dr, _}} when dl <= dr -> {:left, left}
      {_, right} -> {:right, right}
    end
  end

  def wall(lps, side) do
    case Geometry.wall(lps, side) do
      nil -> nil
      wall -> {side, wall}
    end
  end

  @doc "The rule base for a wall on the left."
  @spec rules() :: Fuzzy.rule_base()
  def rules do
    [
      [
        if: {:and, [{:is, :error, :too_close}, {:not, {:is, :approach, :away}}]},
        then: [w: :right]
      ],
      [if: {:and, [{:is, :error, :too_close}, {:is, :approach, :away}]}, then: [w: :straight]],
      [
        if: {:and, [{:is, :error, :too_far}, {:not, {:is, :approach, :towards}}]},
        then: [w: :left]
      ],
      [if: {:and, [{:is, :error, :too_far}, {:is, :approach, :towards}]}, then: [w: :straight]],
      [if: {:and, [{:is, :error, :ok}, {:is, :approach, :towards}]}, then: [w: :right]],
      [if: {:and, [{:is, :error, :ok}, {:is, :approach, :away}]}, then: [w: :left]],
      [if: {:and, [{:is, :error, :ok}, {:is, :approach, :parallel}]}, then: [w: :straight]],
      [if: {:is, :front, :blocked}, then: [v: :slow, w: :hard_right]],
      [if: {:not, {:is, :front, :blocked}}, then: [v: :medium]]
    ]
  end

  @doc "The input variables (`range`: the LPS's)."
  @spec variables(number()) :: [Fuzzy.Variable.t()]
  def variables(range) do
    half_pi = :math.pi() / 2

    [
      Fuzzy.variable(:error, {-range, range},
        too_close: {:left_shoulder, -0.15, 0.0},
        ok: {:triangle, -0.1, 0.0, 0.1},
        too_far: {:right_shoulder, 0.0, 0.15}
      ),
      Fuzzy.variable(:approach, {-half_pi, half_pi},
        towards: {:right_shoulder, 0.05, 0.35},
        parallel: {:triangle, -0.15, 0.0, 0.15},
        away: {:left_shoulder, -0.35, -0.05}
      ),
      Fuzzy.variable(:front, {0.0, range}, blocked: {:left_shoulder, 0.3, 0.6})
    ]
  end
end
