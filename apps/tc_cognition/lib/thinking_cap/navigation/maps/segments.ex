defmodule ThinkingCap.Navigation.Maps.Segments do
  @moduledoc """
  Segment maps: the world as straight line segments `{{x1, y1}, {x2, y2}}`
  (m), from a world description (`from_wdf/2`) or extracted from 2-D points
  such as a laser scan's (`fit/2`).

  `fit/2` is split-and-merge (iterative end-point fit, Douglas–Peucker's
  split): the points, **in order along the contour** (as a scan gives
  them), are cut where two neighbours are farther apart than `max_gap`;
  each run is split at its point farthest from the chord between its ends
  while that distance exceeds `threshold`; neighbouring pieces that fit one
  line within `threshold` are merged back; every piece of at least
  `min_points` points becomes a segment fitted by total least squares
  (orthogonal regression), its ends the projections of its first and last
  points.
  """

  alias ThinkingCap.Config.WDF

  @type point :: {float(), float()}
  @type segment :: {point(), point()}

  @doc """
  The segments of a world: its walls, the edges of its obstacles
  (`obstacles: false` leaves them out) and its closed doors (`closed:`
  names the closed doors, replacing the WDF's `open:` flags, as in
  `ThinkingCap.Navigation.Maps.grid_from_wdf/2`).
  """
  @spec from_wdf(WDF.t(), keyword()) :: [segment()]
  def from_wdf(%WDF{} = wdf, opts \\ []) do
    closed =
      case Keyword.fetch(opts, :closed) do
        {:ok, names} -> MapSet.new(names)
        :error -> wdf.doors |> Enum.reject(& &1.open) |> MapSet.new(& &1.name)
      end

    edges =
      if Keyword.get(opts, :obstacles, true),
        do:
          Enum.flat_map(wdf.obstacles, &Enum.zip(&1.polygon, tl(&1.polygon) ++ [hd(&1.polygon)])),
        else: []

    doors = for door <- wdf.doors, MapSet.member?(closed, door.name), do: {door.from, door.to}
    wdf.walls ++ edges ++ doors
  end

  @doc """
  Line segments fitted to points given in order along a contour. Options:
  `threshold` (the largest distance of a point from its line, m, default
  0.05), `min_points` (default 5), `max_gap` (neighbouring points farther
  apart start a new run, m, default 0.3), `min_length` (shorter segments
  are dropped, m, default 0).
  """
  @spec fit([{number(), number()}], keyword()) :: [segment()]
  def fit(points, opts \\ []) do
    threshold = Keyword.get(opts, :threshold, 0.05)
    min_points = Keyword.get(opts, :min_points, 5)
    max_gap = Keyword.get(opts, :max_gap, 0.3)
    min_length = Keyword.get(opts, :min_length, 0.0)

    points
    |> Enum.map(fn {x, y} -> {x * 1.0, y * 1.0} end)
    |> runs(max_gap)
    |> Enum.flat_map(fn run ->
      run |> split(threshold) |> merge(threshold)
    end)
    |> Enum.filter(&(length(&1) >= min_points))
    |> Enum.map(&line/1)
    |> Enum.filter(fn {{x1, y1}, {x2, y2}} ->
      :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2) >= min_length
    end)
  end

  @doc "The distance from a point to a segment, m."
  @spec distance(point(), segment()) :: float()
  def distance({px, py}, {{x1, y1}, {x2, y2}}) do
    {dx, dy} = {x2 - x1, y2 - y1}
    len2 = dx * dx + dy * dy
    t = if len2 == 0, do: 0.0, else: max(0.0, min(1.0, ((px - x1) * dx + (py - y1) * dy) / len2))
    :math.sqrt((px - x1 - t * dx) ** 2 + (py - y1 - t * dy) ** 2)
  end

  ## split and merge

  defp runs([], _gap), do: []

  defp runs([first | rest], gap) do
    {runs, current} =
      Enum.reduce(rest, {[], [first]}, fn {x, y} = p, {runs, [{px, py} | _] = current} ->
        if (x - px) ** 2 + (y - py) ** 2 > gap * gap,
          do: {[Enum.reverse(current) | runs], [p]},
          else: {runs, [p | current]}
      end)

    Enum.reverse([Enum.reverse(current) | runs])
  end

  # pieces (lists of points) each within threshold of its chord
  defp split(points, _threshold) when length(points) <= 2, do: [points]

  defp split(points, threshold) do
    tuple = List.to_tuple(points)
    n = tuple_size(tuple)
    chord = {elem(tuple, 0), elem(tuple, n - 1)}

    {k, d} =
      Enum.reduce(1..(n - 2), {0, -1.0}, fn i, {k, d} ->
        di = line_distance(elem(tuple, i), chord)
        if di > d, do: {i, di}, else: {k, d}
      end)

    if d > threshold do
      {left, right} = Enum.split(points, k + 1)
      split(left, threshold) ++ split([elem(tuple, k) | right], threshold)
    else
      [points]
    end
  end

  # neighbouring pieces share their joint point; merge those on one line
  defp merge(pieces, threshold) do
    pieces
    |> Enum.reduce([], fn
      piece, [] ->
        [piece]

      piece, [previous | acc] ->
        joined = previous ++ tl(piece)
        if max_residual(joined) <= threshold, do: [joined | acc], else: [piece, previous | acc]
    end)
    |> Enum.reverse()
  end

  # distance from a point to the infinite line through a chord
  defp line_distance({px, py}, {{x1, y1}, {x2, y2}}) do
    {dx, dy} = {x2 - x1, y2 - y1}
    len = :math.sqrt(dx * dx + dy * dy)

    if len == 0,
      do: :math.sqrt((px - x1) ** 2 + (py - y1) ** 2),
      else: abs(dx * (py - y1) - dy * (px - x1)) / len
  end

  ## total least squares

  defp tls(points) do
    n = length(points)
    {sx, sy} = Enum.reduce(points, {0.0, 0.0}, fn {x, y}, {sx, sy} -> {sx + x, sy + y} end)
    {mx, my} = {sx / n, sy / n}

    {sxx, syy, sxy} =
      Enum.reduce(points, {0.0, 0.0, 0.0}, fn {x, y}, {a, b, c} ->
        {a + (x - mx) ** 2, b + (y - my) ** 2, c + (x - mx) * (y - my)}
      end)

    phi = 0.5 * :math.atan2(2 * sxy, sxx - syy)
    {{mx, my}, {:math.cos(phi), :math.sin(phi)}}
  end

  defp max_residual(points) do
    {{mx, my}, {ux, uy}} = tls(points)
    points |> Enum.map(fn {x, y} -> abs(-uy * (x - mx) + ux * (y - my)) end) |> Enum.max()
  end

  defp line(points) do
    {{mx, my}, {ux, uy}} = tls(points)

    project = fn {x, y} ->
      t = (x - mx) * ux + (y - my) * uy
      {mx + t * ux, my + t * uy}
    end

    {project.(hd(points)), project.(List.last(points))}
  end
end
