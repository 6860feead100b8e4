defmodule ThinkingCap.Control.FollowPath do
  @moduledoc """
  Follows the plan's path by pure pursuit: the target is the point
  `lookahead` metres further along the path than the path's point nearest
  the robot (`ThinkingCap.Control.Geometry.lookahead/3`), fed to the rules
  of `ThinkingCap.Control.GoToPoint` with its bearing and, as distance,
  what is left to drive (the path left after the nearest point, or the
  straight distance to the target if larger): the robot slows down near
  the path's end, not near each lookahead point.

  The nearest point is sought over the whole path: a path that comes back
  close to itself may be cut short.

  Context: a path is given and its end is not reached.

  Params: `lookahead: 0.6` (m), and `GoToPoint`'s `tolerance` and
  `slow_distance`.
  """
  use ThinkingCap.Control.Behaviour

  alias ThinkingCap.Control.{Geometry, GoToPoint}

  defstruct lookahead: 0.6, go_to: %GoToPoint{}

  @type t :: %__MODULE__{}

  @impl true
  @spec init(keyword()) :: t()
  def init(params \\ []) do
    {lookahead, rest} = Keyword.pop(params, :lookahead, 0.6)
    %__MODULE__{lookahead: lookahead, go_to: GoToPoint.init(rest)}
  end

  @impl true
  def context(inputs, p) do
    case target(inputs, p) do
      nil -> 0.0
      {distance, _bearing} -> GoToPoint.reached(distance, p.go_to)
    end
  end

  @impl true
  def outputs(inputs, p) do
    case target(inputs, p) do
      nil -> %{}
      {distance, bearing} -> GoToPoint.steer(distance, bearing, inputs, p.go_to)
    end
  end

  @impl true
  def evaluate(inputs, p) do
    case target(inputs, p) do
      nil ->
        {0.0, %{}}

      {distance, bearing} ->
        {GoToPoint.reached(distance, p.go_to),
         GoToPoint.steer(distance, bearing, inputs, p.go_to)}
    end
  end

  @doc """
  The distance left and the bearing (robot frame) of the lookahead point,
  or `nil` without a path.
  """
  @spec target(Behaviour.inputs(), t()) :: {float(), float()} | nil
  def target(%{path: [_ | _] = path, pose: {x, y, _} = pose}, p) do
    {point, remaining} = Geometry.lookahead(path, {x, y}, p.lookahead)
    {direct, bearing} = Geometry.polar(Geometry.to_robot(pose, point))
    {max(remaining, direct), bearing}
  end

  def target(_inputs, _p), do: nil
end
