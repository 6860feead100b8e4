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
  alias ThinkingCap.Navigation.OccupancyGrid
  alias ThinkingCap.Navigation.Core.GridNif

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

  @doc """
  The walls of an occupancy grid as fuzzy segments `{a, b, degree}`: the
  obstacle cells (occupancy at least `threshold`, default 50) that touch a
  known free cell, chained into contours (each cell to an unvisited
  neighbour: straight on first, then sides, then corners), fitted with `fit/2` (`threshold` 1.5
  cells, `max_gap` 2.5 cells, `min_points` 5, `min_length` 0.3 m), each
  with the mean occupancy of the cells near it (within 1.5 cells) as its
  degree in [0, 1].
  """
  @spec from_occupancy(OccupancyGrid.t(), keyword()) :: [{point(), point(), float()}]
  def from_occupancy(%OccupancyGrid{width: w, height: h} = map, opts \\ []) do
    threshold = Keyword.get(opts, :threshold, 50)
    res = map.resolution

    free =
      for <<v::signed-8 <- map.data>>,
        into: <<>>,
        do: <<if(v >= 0 and v < threshold, do: 1, else: 0)>>

    near_free = GridNif.inflate(free, w, h, 1.0)

    border =
      for {i, _} <- :binary.matches(near_free, <<1>>),
          value = :binary.at(map.data, i),
          value < 128 and value >= threshold,
          into: %{},
          do: {{rem(i, w), div(i, w)}, value}

    border
    |> chains()
    |> Enum.flat_map(&cut_reversals/1)
    |> Enum.flat_map(fn chain ->
      points = Enum.map(chain, &centre(map, &1))

      points
      |> fit(threshold: 1.5 * res, max_gap: 2.5 * res, min_points: 5, min_length: 0.3)
      |> Enum.map(fn {a, b} -> {a, b, degree(map, chain, border, {a, b})} end)
    end)
  end

  defp centre(%OccupancyGrid{origin: {ox, oy}, resolution: r}, {c, w}),
    do: {ox + (c + 0.5) * r, oy + (w + 0.5) * r}

  defp degree(map, chain, border, segment) do
    near =
      for cell <- chain,
          distance(centre(map, cell), segment) <= 1.5 * map.resolution,
          do: Map.fetch!(border, cell)

    if near == [], do: 1.0, else: Enum.sum(near) / length(near) / 100
  end

  @steps [{1, 0}, {0, 1}, {-1, 0}, {0, -1}, {1, 1}, {-1, 1}, {-1, -1}, {1, -1}]

  # the cells chained into contours. A contour starts at a cell with the
  # fewest neighbours (the end of a wall) and walks one way, straight on
  # while it can (so a wall meeting another at a T, or the second row of
  # a wall two cells thick, is a contour of its own), else to a side
  # neighbour, else a corner one
  defp chains(cells) do
    neighbours = fn {c, r} ->
      Enum.count(@steps, fn {dc, dr} -> Map.has_key?(cells, {c + dc, r + dr}) end)
    end

    {chains, _} =
      cells
      |> Map.keys()
      |> Enum.sort_by(&{neighbours.(&1), &1})
      |> Enum.reduce({[], MapSet.new()}, fn cell, {chains, seen} ->
        if MapSet.member?(seen, cell) do
          {chains, seen}
        else
          {forward, seen} = walk(cell, nil, cells, MapSet.put(seen, cell), [])
          {[[cell | forward] | chains], seen}
        end
      end)

    Enum.reverse(chains)
  end

  # a contour that turns back on itself (round the end of a wall two
  # cells thick) is cut where it turns: two cells back and two on point
  # more than 120° apart
  defp cut_reversals(chain) when length(chain) < 5, do: [chain]

  defp cut_reversals(chain) do
    t = List.to_tuple(chain)
    n = tuple_size(t)

    cuts =
      for i <- 2..(n - 3),
          {ax, ay} = sub(elem(t, i), elem(t, i - 2)),
          {bx, by} = sub(elem(t, i + 2), elem(t, i)),
          ax * bx + ay * by < -0.5 * :math.sqrt((ax * ax + ay * ay) * (bx * bx + by * by)),
          do: i

    cuts
    |> Enum.reduce({[], 0}, fn i, {pieces, from} ->
      if i - from >= 2, do: {[{from, i} | pieces], i + 1}, else: {pieces, from}
    end)
    |> then(fn {pieces, from} -> Enum.reverse([{from, n - 1} | pieces]) end)
    |> Enum.map(fn {a, b} -> Enum.slice(chain, a..b) end)
  end

  defp sub({a, b}, {c, d}), do: {a - c, b - d}

  defp walk({c, r}, heading, cells, seen, acc) do
    steps = if heading, do: [heading | @steps], else: @steps

    next =
      Enum.find_value(steps, fn {dc, dr} = step ->
        n = {c + dc, r + dr}
        if Map.has_key?(cells, n) and not MapSet.member?(seen, n), do: {n, step}
      end)

    case next do
      nil -> {Enum.reverse(acc), seen}
      {n, step} -> walk(n, step, cells, MapSet.put(seen, n), [n | acc])
    end
  end

  @doc """
  The distance from a point to a segment, m: `ThinkingCap.Geometry.segment_distance/3`
  for a segment given as one `{a, b}` tuple.
  """
  @spec distance(point(), segment()) :: float()
  def distance(point, {a, b}), do: ThinkingCap.Geometry.segment_distance(point, a, b)

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
