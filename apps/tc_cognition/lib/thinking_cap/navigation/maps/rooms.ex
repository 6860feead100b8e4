defmodule ThinkingCap.Navigation.Maps.Rooms do
  @moduledoc """
  The topological map of an occupancy grid: its rooms and corridors, and
  the doors between them (`ThinkingCap.Navigation.Topology`), found by
  morphological segmentation of the known free space:

    1. **cores**: the free cells farther than `door_width / 2` from
       anything not known free (the distance transform of
       `c_src/tc_grid.c`). A door is narrower than that, so the free space
       falls apart at doors into one core per room; cores smaller than
       `min_area` are dropped;
    2. **regions**: every free cell joins the core it reaches first,
       growing breadth first from all cores at once;
    3. **doors**: where two regions touch. A contact wider than
       `door_width` is not a door (one room that furniture narrows): its
       two regions are merged. A door is named by its place in the map
       and carries its jambs (the ends of the contact), centre and width;
    4. **places**: the regions of at least `min_area`, a `:corridor` when
       their cells spread over one axis more than `corridor_ratio` times
       the other, else a `:room`; their polygon is the convex hull of
       their cells, their centroid the mean of their cells (moved to the
       nearest of their cells if it falls outside).

  Names are `room_1`, `room_2`, ... and `corridor_1`, ... in the order of
  their centroids (top row first, then left to right), and `door_1`, ...
  likewise; `rename/2` carries names over from an earlier map, so that a
  room keeps its name while the map grows.
  """

  alias ThinkingCap.Navigation.{OccupancyGrid, Topology}
  alias ThinkingCap.Navigation.Core.GridNif

  @type opts :: [
          door_width: float(),
          min_area: float(),
          corridor_ratio: float(),
          min_door: float(),
          free_below: 0..100
        ]

  @doc """
  The topological map of `map`. Options: `door_width` (the widest door,
  m, default 1.2), `min_area` (m², default 1.5), `corridor_ratio`
  (default 3), `min_door` (a narrower gap between two regions is no
  door, m, default 0.5), `free_below` (the occupancy under which a known cell is
  free, default 20 as `map_saver`'s free threshold: a weakly seen wall
  must not join two rooms).
  """
  @spec from_occupancy(OccupancyGrid.t(), opts()) :: Topology.t()
  def from_occupancy(%OccupancyGrid{width: w, height: h} = map, opts \\ []) do
    res = map.resolution
    door_width = Keyword.get(opts, :door_width, 1.2)
    min_cells = Keyword.get(opts, :min_area, 1.5) / (res * res)
    free_below = Keyword.get(opts, :free_below, 20)
    max_cells = door_width / res
    min_cells_door = Keyword.get(opts, :min_door, 0.5) / res

    # cores, regions and their contacts (c_src/tc_grid.c); cores smaller
    # than a quarter of the smallest place are noise
    {regions, touching} =
      GridNif.rooms(map.data, w, h, free_below, door_width / 2 / res, min_cells / 4)

    regions = Map.new(regions, &{elem(&1, 0), region(&1)})

    # each stretch of contact between two regions is a door candidate; a
    # gap narrower than a door (a weakly seen wall) is none
    contacts =
      for {pair, points} <- Enum.group_by(touching, &{elem(&1, 0), elem(&1, 1)}, &half_cell/1),
          stretch <- stretches(points),
          extent(stretch) >= min_cells_door,
          do: {pair, stretch}

    {wide, narrow} = Enum.split_with(contacts, fn {_pair, pts} -> extent(pts) > max_cells end)
    merged = merge(Map.keys(regions), Enum.map(wide, &elem(&1, 0)))

    regions =
      regions
      |> Enum.group_by(fn {label, _} -> Map.fetch!(merged, label) end, &elem(&1, 1))
      |> Map.new(fn {root, parts} -> {root, Enum.reduce(parts, &join/2)} end)
      |> Map.filter(fn {_root, region} -> region.count >= min_cells end)

    places = places(map, regions, Keyword.get(opts, :corridor_ratio, 3.0))
    doors = doors(map, narrow, merged, places)

    %Topology{
      places: Map.new(places, fn {_root, p} -> {p.name, p} end),
      doors: Map.new(doors, &{&1.name, &1})
    }
  end

  # a region's cell count, coordinate sums and the extent of each of its rows
  defp region({_label, n, sc, sr, scc, scr, srr, rows}),
    do: %{
      count: n,
      sums: {sc, sr, scc, scr, srr},
      rows: Map.new(rows, fn {r, a, b} -> {r, {a, b}} end)
    }

  defp join(a, b) do
    {a1, a2, a3, a4, a5} = a.sums
    {b1, b2, b3, b4, b5} = b.sums

    %{
      count: a.count + b.count,
      sums: {a1 + b1, a2 + b2, a3 + b3, a4 + b4, a5 + b5},
      rows: Map.merge(a.rows, b.rows, fn _r, {p, q}, {u, v} -> {min(p, u), max(q, v)} end)
    }
  end

  # a contact on the edge between two cells, in cell-corner coordinates
  defp half_cell({_a, _b, x2, y2}), do: {x2 / 2, y2 / 2}

  @doc """
  Carries names over from `previous`: a place whose centroid lies in a
  place of the new map gives that place its name (the largest place
  first), and a door within 0.5 m of an old door takes its name; the others
  are numbered on from the highest number in use.
  """
  @spec rename(Topology.t(), Topology.t() | nil) :: Topology.t()
  def rename(topology, nil), do: topology

  def rename(%Topology{} = new, %Topology{} = old) do
    place_names =
      new.places
      |> Map.values()
      |> Enum.sort_by(&(-area(&1.polygon)))
      |> assign(Map.values(old.places), fn p, o ->
        p.kind == o.kind and inside_or_near?(o.centroid, p)
      end)

    places = Map.new(new.places, fn {name, p} -> relabel(name, p, place_names) end)
    place_name = fn name -> Map.get(place_names, name, name) end

    door_names =
      new.doors
      |> Map.values()
      |> assign(Map.values(old.doors), fn d, o -> dist(d.centre, o.centre) < 0.5 end)

    doors =
      Map.new(new.doors, fn {name, d} ->
        {n, d} = relabel(name, d, door_names)
        {n, %{d | connects: Enum.map(d.connects, place_name)}}
      end)

    %Topology{places: places, doors: doors}
  end

  # old names given to new items, then fresh numbers for the rest
  defp assign(new_items, old_items, match?) do
    {names, _taken} =
      Enum.reduce(new_items, {%{}, MapSet.new()}, fn item, {names, taken} ->
        case Enum.find(old_items, &(match?.(item, &1) and not MapSet.member?(taken, &1.name))) do
          nil -> {names, taken}
          old -> {Map.put(names, item.name, old.name), MapSet.put(taken, old.name)}
        end
      end)

    used = Map.values(names) ++ Enum.map(old_items, & &1.name)

    {names, _} =
      new_items
      |> Enum.reject(&Map.has_key?(names, &1.name))
      |> Enum.reduce({names, used}, fn item, {names, used} ->
        prefix = item.name |> Atom.to_string() |> String.replace(~r/_\d+$/, "")
        name = next_name(prefix, used)
        {Map.put(names, item.name, name), [name | used]}
      end)

    names
  end

  defp next_name(prefix, used) do
    n =
      used
      |> Enum.map(&Atom.to_string/1)
      |> Enum.flat_map(fn s ->
        case Regex.run(~r/^#{prefix}_(\d+)$/, s) do
          [_, d] -> [String.to_integer(d)]
          nil -> []
        end
      end)
      |> Enum.max(fn -> 0 end)

    # the prefixes are this module's own: room, corridor, door
    String.to_atom("#{prefix}_#{n + 1}")
  end

  defp relabel(name, item, names) do
    new = Map.get(names, name, name)
    {new, %{item | name: new}}
  end

  defp inside_or_near?(point, place),
    do: inside?(point, place.polygon) or dist(point, place.centroid) < 1.0

  defp area(polygon) do
    polygon
    |> Enum.zip(tl(polygon) ++ [hd(polygon)])
    |> Enum.reduce(0.0, fn {{x1, y1}, {x2, y2}}, a -> a + x1 * y2 - x2 * y1 end)
    |> abs()
    |> Kernel./(2)
  end

  ## regions

  # contact points split into stretches of neighbours (at most a cell apart)
  defp stretches(points) do
    set = MapSet.new(points)

    {groups, _} =
      Enum.reduce(Enum.sort(points), {[], MapSet.new()}, fn p, {groups, seen} ->
        if MapSet.member?(seen, p) do
          {groups, seen}
        else
          {group, seen} = spread([p], set, MapSet.put(seen, p), [])
          {[group | groups], seen}
        end
      end)

    groups
  end

  defp spread([], _set, seen, acc), do: {acc, seen}

  defp spread([{x, y} = p | rest], set, seen, acc) do
    next =
      for dx <- [-1, -0.5, 0, 0.5, 1],
          dy <- [-1, -0.5, 0, 0.5, 1],
          n = {x + dx, y + dy},
          MapSet.member?(set, n) and not MapSet.member?(seen, n),
          do: n

    spread(next ++ rest, set, Enum.reduce(next, seen, &MapSet.put(&2, &1)), [p | acc])
  end

  # the largest distance between two contact points (cells)
  defp extent(points) do
    {{x0, y0}, {x1, y1}} = ends(points)
    :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2) + 1
  end

  # the two points farthest apart along the contact's main direction
  defp ends(points) do
    {mx, my} = mean(points)

    {sxx, sxy, syy} =
      Enum.reduce(points, {0.0, 0.0, 0.0}, fn {x, y}, {a, b, c} ->
        {a + (x - mx) ** 2, b + (x - mx) * (y - my), c + (y - my) ** 2}
      end)

    angle = 0.5 * :math.atan2(2 * sxy, sxx - syy)
    {dx, dy} = {:math.cos(angle), :math.sin(angle)}
    key = fn {x, y} -> (x - mx) * dx + (y - my) * dy end
    {Enum.min_by(points, key), Enum.max_by(points, key)}
  end

  defp mean(points) do
    {sx, sy} = Enum.reduce(points, {0.0, 0.0}, fn {x, y}, {a, b} -> {a + x, b + y} end)
    n = length(points)
    {sx / n, sy / n}
  end

  # union-find over labels joined by wide contacts: label -> root
  defp merge(labels, pairs) do
    parent = Map.new(labels, &{&1, &1})

    parent =
      Enum.reduce(pairs, parent, fn {a, b}, parent ->
        {ra, rb} = {root(parent, a), root(parent, b)}
        if ra == rb, do: parent, else: Map.put(parent, max(ra, rb), min(ra, rb))
      end)

    Map.new(labels, &{&1, root(parent, &1)})
  end

  defp root(parent, a) do
    case Map.fetch!(parent, a) do
      ^a -> a
      p -> root(parent, p)
    end
  end

  ## places and doors

  defp places(map, regions, corridor_ratio) do
    described =
      for {root, region} <- regions do
        {cx, cy} = inside(region, centre(region))
        kind = if elongation(region) > corridor_ratio, do: :corridor, else: :room
        polygon = region |> corners() |> hull() |> Enum.map(&world(map, &1))
        {root, kind, world(map, {cx + 0.5, cy + 0.5}), polygon}
      end

    described
    |> Enum.sort_by(fn {_, _, {x, y}, _} -> {-y, x} end)
    |> Enum.group_by(fn {_, kind, _, _} -> kind end)
    |> Enum.flat_map(fn {_kind, list} ->
      list
      |> Enum.with_index(1)
      |> Enum.map(fn {{root, kind, centroid, polygon}, i} ->
        {root, %{name: :"#{kind}_#{i}", kind: kind, polygon: polygon, centroid: centroid}}
      end)
    end)
    |> Map.new()
  end

  defp centre(%{count: n, sums: {sc, sr, _, _, _}}), do: {sc / n, sr / n}

  # the point itself if the region's row there holds it, else the nearest
  # point of the region's rows
  defp inside(%{rows: rows}, {cx, cy}) do
    case Map.get(rows, round(cy)) do
      {a, b} when a <= round(cx) and round(cx) <= b ->
        {cx, cy}

      _ ->
        rows
        |> Enum.map(fn {r, {a, b}} -> {min(max(cx, a * 1.0), b * 1.0), r * 1.0} end)
        |> Enum.min_by(fn {x, y} -> (x - cx) ** 2 + (y - cy) ** 2 end)
    end
  end

  # the square root of the ratio of the principal second moments
  defp elongation(%{count: n, sums: {sc, sr, scc, scr, srr}}) do
    {mx, my} = {sc / n, sr / n}
    {a, b, c} = {scc / n - mx * mx, scr / n - mx * my, srr / n - my * my}
    d = :math.sqrt(((a - c) / 2) ** 2 + b * b)
    {l1, l2} = {(a + c) / 2 + d, max((a + c) / 2 - d, 1.0e-9)}
    :math.sqrt(l1 / l2)
  end

  # the corners of each row's first and last cells
  defp corners(%{rows: rows}),
    do:
      Enum.flat_map(rows, fn {r, {a, b}} -> [{a, r}, {b + 1, r}, {a, r + 1}, {b + 1, r + 1}] end)

  defp doors(map, contacts, merged, places) do
    contacts
    |> Enum.flat_map(fn {{a, b}, points} ->
      {ra, rb} = {Map.fetch!(merged, a), Map.fetch!(merged, b)}

      with false <- ra == rb,
           %{name: pa} <- Map.get(places, ra),
           %{name: pb} <- Map.get(places, rb) do
        {p, q} = ends(points)
        {from, to} = {world(map, p), world(map, q)}

        [
          %{
            name: nil,
            centre: world(map, mean(points)),
            connects: Enum.sort([pa, pb]),
            open: true,
            from: from,
            to: to,
            width: extent(points) * map.resolution
          }
        ]
      else
        _ -> []
      end
    end)
    |> Enum.sort_by(fn %{centre: {x, y}} -> {-y, x} end)
    |> Enum.with_index(1)
    |> Enum.map(fn {d, i} -> %{d | name: :"door_#{i}"} end)
  end

  defp world(%OccupancyGrid{origin: {ox, oy}, resolution: res}, {c, r}),
    do: {ox + c * res, oy + r * res}

  # the convex hull of points (monotone chain), counter-clockwise
  defp hull(points) do
    corners = points |> Enum.uniq() |> Enum.sort()

    lower = chain(corners)
    upper = chain(Enum.reverse(corners))
    Enum.drop(lower, -1) ++ Enum.drop(upper, -1)
  end

  defp chain(points) do
    points
    |> Enum.reduce([], fn p, acc -> [p | pop(acc, p)] end)
    |> Enum.reverse()
  end

  defp pop([b, a | rest], p) do
    if cross(a, b, p) <= 0, do: pop([a | rest], p), else: [b, a | rest]
  end

  defp pop(acc, _p), do: acc

  defp cross({ax, ay}, {bx, by}, {px, py}), do: (bx - ax) * (py - ay) - (by - ay) * (px - ax)

  defp inside?({x, y}, polygon) do
    polygon
    |> Enum.zip(tl(polygon) ++ [hd(polygon)])
    |> Enum.reduce(false, fn {{x1, y1}, {x2, y2}}, inside ->
      if y1 > y != y2 > y and x < (x2 - x1) * (y - y1) / (y2 - y1) + x1,
        do: not inside,
        else: inside
    end)
  end

  defp dist({ax, ay}, {bx, by}), do: :math.sqrt((ax - bx) ** 2 + (ay - by) ** 2)
end
