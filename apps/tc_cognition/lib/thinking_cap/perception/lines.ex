defmodule ThinkingCap.Perception.Lines do
  @moduledoc """
  Straight walls and door openings in the LPS: segments fitted to the
  robot-frame obstacle points (split-and-merge,
  `ThinkingCap.Navigation.Maps.Segments.fit/2`, over the points in order
  of bearing), and openings between the ends of neighbouring segments that
  are as wide as a door.
  """

  alias ThinkingCap.Navigation.Maps.Segments

  @type point :: {float(), float()}
  @type segment :: {point(), point()}

  @door_width {0.6, 1.6}

  @doc "Segments through robot-frame `points`, within `tolerance` metres."
  @spec fit([point()], float()) :: [segment()]
  def fit(points, _tolerance) when length(points) < 4, do: []

  def fit(points, tolerance) do
    points
    |> Enum.sort_by(fn {x, y} -> :math.atan2(y, x) end)
    |> Segments.fit(threshold: tolerance, min_points: 4)
  end

  @doc """
  Door-wide gaps between the ends of neighbouring segments (in order of
  bearing), within `range` of the robot: `%{centre:, width:, heading:}`,
  heading pointing away from the robot.
  """
  @spec openings([segment()], float()) :: [%{centre: point(), width: float(), heading: float()}]
  def openings(segments, range) do
    {min_w, max_w} = @door_width

    ends =
      segments
      |> Enum.map(fn {a, b} -> if bearing(a) <= bearing(b), do: {a, b}, else: {b, a} end)
      |> Enum.sort_by(fn {a, _b} -> bearing(a) end)

    ends
    |> Enum.zip(Enum.drop(ends, 1))
    |> Enum.flat_map(fn {{_, {x1, y1}}, {{x2, y2}, _}} ->
      width = :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)
      centre = {(x1 + x2) / 2, (y1 + y2) / 2}
      {cx, cy} = centre

      if width >= min_w and width <= max_w and :math.sqrt(cx * cx + cy * cy) <= range,
        do: [%{centre: centre, width: width, heading: :math.atan2(cy, cx)}],
        else: []
    end)
  end

  defp bearing({x, y}), do: :math.atan2(y, x)
end
