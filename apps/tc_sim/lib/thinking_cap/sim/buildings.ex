defmodule ThinkingCap.Sim.Buildings do
  @moduledoc """
  Draws building-like worlds as occupancy maps (the ROS `map_server`
  layout of `ThinkingCap.Config.RosMap`, 5 cm cells): outer walls,
  corridors, rooms with doors 0.8–1.0 m wide, and furniture (desks,
  shelves, cabinets, pillars in large halls). The same seed draws the same
  building; every free cell is reachable from the start.

      {:ok, building} = ThinkingCap.Sim.Buildings.generate(seed: 7, size: {30, 20})
      :ok = ThinkingCap.Sim.Buildings.save(building, "tmp/office7.yaml")

  How it is drawn:

    * the building is split recursively, first by corridors (1.6–2.2 m
      wide, each one across the part it splits and perpendicular to the
      corridor it leaves from, so the corridors are connected), then by
      walls into rooms of 2.5 m to 7 m a side (now and then a hall of up to
      12 m);
    * doors join every room to a corridor or, failing that, to a room
      already joined (a spanning tree over the rooms), plus a few extra
      doors between rooms; a door keeps 0.25 m of wall at each side;
    * furniture stands flush against a wall or at least 0.7 m from it, at
      least 0.7 m from other furniture and 1.2 m clear of the doors, so a
      robot can pass wherever there is a gap.

  Interior walls are 10 cm thick, outer walls 20 cm; outside the building
  the map is unknown (a 0.5 m margin).
  """

  alias ThinkingCap.Config.RosMap

  @res 0.05
  # all lengths below are in cells of 5 cm
  @margin 10
  @outer 4
  @min_room 50
  @corridor_side 70
  @door_clear 5
  @gap 14
  @door_zone 24

  @typedoc "A rectangle of cells, `{x0, y0, x1, y1}`, half-open."
  @type rect :: {integer(), integer(), integer(), integer()}

  @typedoc """
  A generated building. `map` is ready for `ThinkingCap.Config.RosMap.save/2`
  (and `ThinkingCap.Sim.Raycast.new/1`); the rest says, in metres, what
  was drawn: rooms and corridors as `{x0, y0, x1, y1}` rectangles, doors
  with their centre, clear width and the axis the wall runs along,
  furniture with its kind and rectangle, and a free start point in the
  first corridor (or the first room).
  """
  @type t :: %{
          map: %{
            width: pos_integer(),
            height: pos_integer(),
            resolution: float(),
            origin: {float(), float(), float()},
            data: binary()
          },
          seed: integer(),
          rooms: [%{rect: {float(), float(), float(), float()}, kind: :room | :hall}],
          corridors: [{float(), float(), float(), float()}],
          doors: [%{at: {float(), float()}, width: float(), axis: :x | :y}],
          furniture: [%{kind: atom(), rect: {float(), float(), float(), float()}}],
          start: {float(), float()}
        }

  @doc """
  Draws a building. Options: `seed:` an integer (default 1), `size:`
  `{width, height}` of the building in metres (default `{30, 20}`, each
  side 6 m to 200 m).
  """
  @spec generate(keyword()) :: {:ok, t()} | {:error, String.t()}
  def generate(opts \\ []) do
    with {:ok, seed} <- seed(Keyword.get(opts, :seed, 1)),
         {:ok, {w, h}} <- size(Keyword.get(opts, :size, {30, 20})) do
      {:ok, draw(seed, w, h)}
    end
  end

  @doc "Saves the building's map as `map_server` YAML + PGM (`ThinkingCap.Config.RosMap.save/2`)."
  @spec save(t(), Path.t()) :: :ok | {:error, String.t()}
  def save(%{map: map}, yaml_path) do
    dir = Path.dirname(yaml_path)

    case File.mkdir_p(dir) do
      :ok -> RosMap.save(map, yaml_path)
      {:error, reason} -> {:error, "cannot create #{dir}: #{:file.format_error(reason)}"}
    end
  end

  @doc """
  Parses a size given as `"WxH"` metres (as `mix tc.map.generate --size`
  takes it).
  """
  @spec parse_size(String.t()) :: {:ok, {float(), float()}} | {:error, String.t()}
  def parse_size(text) do
    with [w, h] <- String.split(text, ["x", "X"]),
         {w, ""} <- Float.parse(w),
         {h, ""} <- Float.parse(h),
         {:ok, size} <- size({w, h}) do
      {:ok, size}
    else
      _ -> {:error, "size: #{inspect(text)} is not WxH in metres, each 6 to 200 (e.g. 30x20)"}
    end
  end

  defp seed(seed) when is_integer(seed), do: {:ok, seed}
  defp seed(other), do: {:error, "seed: #{inspect(other)} is not an integer"}

  defp size({w, h})
       when is_number(w) and is_number(h) and w >= 6 and h >= 6 and w <= 200 and h <= 200,
       do: {:ok, {w * 1.0, h * 1.0}}

  defp size(other),
    do: {:error, "size: #{inspect(other)} is not {width, height} in metres, each 6 to 200"}

  ## Layout

  defp draw(seed, w_m, h_m) do
    rng = :rand.seed_s(:exsss, {seed, 4_231, 17})
    bw = round(w_m / @res)
    bh = round(h_m / @res)
    width = bw + 2 * @margin
    height = bh + 2 * @margin
    inner = {@margin + @outer, @margin + @outer, @margin + bw - @outer, @margin + bh - @outer}

    {leaves, rng} = corridor_phase(inner, nil, rng)
    corridors = for {:corridor, r} <- leaves, do: r
    rooms = for {kind, r} <- leaves, kind in [:room, :hall], do: {kind, r}
    {doors, rng} = doors(corridors, Enum.map(rooms, &elem(&1, 1)), rng)
    {furniture, _rng} = furnish(rooms, doors, rng)

    raster = :atomics.new(width * height, signed: true)
    put = fn x, y, v -> :atomics.put(raster, y * width + x + 1, v) end

    fill = fn {x0, y0, x1, y1}, v ->
      for y <- y0..(y1 - 1)//1, x <- x0..(x1 - 1)//1, do: put.(x, y, v)
    end

    # unknown outside, walls, free inside
    fill.({0, 0, width, height}, -1)
    fill.({@margin, @margin, @margin + bw, @margin + bh}, 100)
    fill.(inner, 0)
    Enum.each(rooms, fn {_kind, r} -> Enum.each(walls(r), &fill.(&1, 100)) end)
    Enum.each(doors, fn d -> fill.(d.cells, 0) end)
    Enum.each(furniture, fn f -> fill.(f.cells, 100) end)

    data = for i <- 1..(width * height), into: <<>>, do: <<:atomics.get(raster, i)::signed-8>>
    start = start_point(corridors, rooms, doors)

    %{
      map: %{
        width: width,
        height: height,
        resolution: @res,
        origin: {0.0, 0.0, 0.0},
        data: data
      },
      seed: seed,
      rooms: for({kind, r} <- rooms, do: %{rect: metres(r), kind: kind}),
      corridors: Enum.map(corridors, &metres/1),
      doors: for(d <- doors, do: Map.take(d, [:at, :width, :axis])),
      furniture: for(f <- furniture, do: %{kind: f.kind, rect: metres(f.cells)}),
      start: start
    }
  end

  defp metres({x0, y0, x1, y1}), do: {x0 * @res, y0 * @res, x1 * @res, y1 * @res}

  # The walls of a room: 2 cells centred on each edge.
  defp walls({x0, y0, x1, y1}) do
    [
      {x0 - 1, y0 - 1, x1 + 1, y0 + 1},
      {x0 - 1, y1 - 1, x1 + 1, y1 + 1},
      {x0 - 1, y0 - 1, x0 + 1, y1 + 1},
      {x1 - 1, y0 - 1, x1 + 1, y1 + 1}
    ]
  end

  # Split by corridors while a part is large: each corridor runs across the
  # part, perpendicular to the corridor its part was cut from.
  defp corridor_phase({x0, y0, x1, y1} = r, parent, rng) do
    {cw, rng} = uniform_int(rng, 32, 44)
    {go, rng} = :rand.uniform_s(rng)
    w = x1 - x0
    h = y1 - y0
    # :h is a corridor running along x, cutting the height
    fits = fn
      :h -> h >= 2 * @corridor_side + cw and w >= 120
      :v -> w >= 2 * @corridor_side + cw and h >= 120
    end

    # the long axis first; a later corridor cuts a long part (or by chance)
    options =
      [if(w >= h, do: :h, else: :v), if(w >= h, do: :v, else: :h)]
      |> Enum.filter(&(&1 != parent and fits.(&1)))
      |> Enum.filter(fn dir -> parent == nil or cut_length(r, dir) >= 320 or go < 0.3 end)

    case options do
      [dir | _] ->
        span = if dir == :h, do: h, else: w
        {at, rng} = uniform_int(rng, @corridor_side, span - @corridor_side - cw)

        {corridor, a, b} =
          case dir do
            :h ->
              {{x0, y0 + at, x1, y0 + at + cw}, {x0, y0, x1, y0 + at}, {x0, y0 + at + cw, x1, y1}}

            :v ->
              {{x0 + at, y0, x0 + at + cw, y1}, {x0, y0, x0 + at, y1}, {x0 + at + cw, y0, x1, y1}}
          end

        {la, rng} = corridor_phase(a, dir, rng)
        {lb, rng} = corridor_phase(b, dir, rng)
        {[{:corridor, corridor} | la] ++ lb, rng}

      [] ->
        room_phase(r, rng)
    end
  end

  # the side a corridor cuts across
  defp cut_length({_, y0, _, y1}, :h), do: y1 - y0
  defp cut_length({x0, _, x1, _}, :v), do: x1 - x0

  # Split by walls into rooms (BSP): the longer side first, both parts at
  # least @min_room; stop at a side of 4.5–7 m, or keep a hall.
  defp room_phase({x0, y0, x1, y1} = r, rng) do
    w = x1 - x0
    h = y1 - y0
    {limit, rng} = uniform_int(rng, 90, 140)
    {u, rng} = :rand.uniform_s(rng)
    long = max(w, h)

    cond do
      long <= limit or long < 2 * @min_room ->
        {[{:room, r}], rng}

      long <= 240 and min(w, h) >= 100 and u < 0.15 ->
        {[{:hall, r}], rng}

      true ->
        {at, rng} = uniform_int(rng, @min_room, long - @min_room)

        {a, b} =
          if w >= h,
            do: {{x0, y0, x0 + at, y1}, {x0 + at, y0, x1, y1}},
            else: {{x0, y0, x1, y0 + at}, {x0, y0 + at, x1, y1}}

        {la, rng} = room_phase(a, rng)
        {lb, rng} = room_phase(b, rng)
        {la ++ lb, rng}
    end
  end

  ## Doors

  # A spanning tree over rooms and corridors (corridors join each other
  # where they meet), rooms joined to corridors first; then extra doors.
  defp doors(corridors, rooms, rng) do
    regions = Enum.map(corridors, &{:corridor, &1}) ++ Enum.map(rooms, &{:room, &1})
    indexed = Enum.with_index(regions)

    pairs =
      for {{ka, a}, i} <- indexed,
          {{kb, b}, j} <- indexed,
          i < j,
          edge = shared_edge(a, b),
          edge != nil,
          do: {i, j, ka, kb, edge}

    joined =
      case corridors do
        [] -> MapSet.new([0])
        _ -> MapSet.new(0..(length(corridors) - 1))
      end

    {tree, rng} = spanning(pairs, joined, length(regions), [], rng)

    # a few more doors between rooms
    {extra, rng} =
      Enum.flat_map_reduce(pairs, rng, fn {i, j, ka, kb, _} = pair, rng ->
        {u, rng} = :rand.uniform_s(rng)
        used = Enum.any?(tree, fn {p, _} -> elem(p, 0) == i and elem(p, 1) == j end)

        if ka == :room and kb == :room and not used and u < 0.15,
          do: {[pair], rng},
          else: {[], rng}
      end)

    Enum.map_reduce(Enum.map(tree, &elem(&1, 0)) ++ extra, rng, fn {_, _, _, _, edge}, rng ->
      door(edge, rng)
    end)
  end

  defp spanning(pairs, joined, n, acc, rng) do
    if MapSet.size(joined) == n do
      {Enum.reverse(acc), rng}
    else
      candidates =
        for {i, j, ka, kb, _} = p <- pairs,
            MapSet.member?(joined, i) != MapSet.member?(joined, j),
            not (ka == :corridor and kb == :corridor),
            do: {p, if(ka == :corridor or kb == :corridor, do: 0, else: 1)}

      case candidates do
        [] ->
          # corridors that meet need no door; anything else is unreachable (not drawn so)
          {Enum.reverse(acc), rng}

        _ ->
          best = candidates |> Enum.map(&elem(&1, 1)) |> Enum.min()
          choices = for {p, rank} <- candidates, rank == best, do: p
          {k, rng} = uniform_int(rng, 0, length(choices) - 1)
          {i, j, _, _, _} = pick = Enum.at(choices, k)
          joined = joined |> MapSet.put(i) |> MapSet.put(j)
          spanning(pairs, joined, n, [{pick, :tree} | acc], rng)
      end
    end
  end

  # The edge two rectangles share, when long enough for a door:
  # {:x, y, from, to} (a wall along x at y) or {:y, x, from, to}.
  defp shared_edge({ax0, ay0, ax1, ay1}, {bx0, by0, bx1, by1}) do
    need = 20 + 2 * (@door_clear + 1)

    cond do
      (ax1 == bx0 or bx1 == ax0) and min(ay1, by1) - max(ay0, by0) >= need ->
        {:y, if(ax1 == bx0, do: ax1, else: ax0), max(ay0, by0), min(ay1, by1)}

      (ay1 == by0 or by1 == ay0) and min(ax1, bx1) - max(ax0, bx0) >= need ->
        {:x, if(ay1 == by0, do: ay1, else: ay0), max(ax0, bx0), min(ax1, bx1)}

      true ->
        nil
    end
  end

  # a door of 16–20 cells somewhere along the edge, clear of its ends
  defp door({axis, s, from, to}, rng) do
    {wd, rng} = uniform_int(rng, 16, 20)
    {p, rng} = uniform_int(rng, from + 1 + @door_clear, to - 1 - @door_clear - wd)

    cells =
      case axis do
        :x -> {p, s - 1, p + wd, s + 1}
        :y -> {s - 1, p, s + 1, p + wd}
      end

    centre =
      case axis do
        :x -> {(p + wd / 2) * @res, s * @res}
        :y -> {s * @res, (p + wd / 2) * @res}
      end

    {%{axis: axis, at: centre, width: wd * @res, cells: cells}, rng}
  end

  ## Furniture

  defp furnish(rooms, doors, rng) do
    Enum.flat_map_reduce(rooms, rng, fn {kind, r}, rng ->
      zones = for d <- doors, touches?(d.cells, r), do: door_zone(d.cells)
      {x0, y0, x1, y1} = r
      area = (x1 - x0) * (y1 - y0) * @res * @res
      tries = round(area / 2.5) + 4
      wanted = max(1, round(area / if(kind == :hall, do: 7, else: 5)))
      place(kind, inside(r), zones, wanted, tries, [], rng)
    end)
  end

  # the free inside of a room (its walls take one cell at each edge)
  defp inside({x0, y0, x1, y1}), do: {x0 + 1, y0 + 1, x1 - 1, y1 - 1}

  defp touches?({ax0, ay0, ax1, ay1}, {bx0, by0, bx1, by1}),
    do: ax0 <= bx1 and bx0 <= ax1 and ay0 <= by1 and by0 <= ay1

  defp door_zone({x0, y0, x1, y1}),
    do: {x0 - @door_zone, y0 - @door_zone, x1 + @door_zone, y1 + @door_zone}

  defp place(_kind, _room, _zones, 0, _tries, acc, rng), do: {acc, rng}
  defp place(_kind, _room, _zones, _wanted, 0, acc, rng), do: {acc, rng}

  defp place(kind, room, zones, wanted, tries, acc, rng) do
    {piece, rng} = piece(kind, room, rng)

    if piece != nil and fits?(piece.cells, room, zones, acc),
      do: place(kind, room, zones, wanted - 1, tries - 1, [piece | acc], rng),
      else: place(kind, room, zones, wanted, tries - 1, acc, rng)
  end

  # a desk, cabinet or shelf (against a wall or standing free), or in a
  # hall a pillar
  defp piece(room_kind, {x0, y0, x1, y1}, rng) do
    {u, rng} = :rand.uniform_s(rng)

    {kind, {a, b}, rng} =
      cond do
        room_kind == :hall and u < 0.3 ->
          {s, rng} = uniform_int(rng, 6, 10)
          {:pillar, {s, s}, rng}

        u < 0.6 ->
          {l, rng} = uniform_int(rng, 24, 32)
          {d, rng} = uniform_int(rng, 12, 16)
          {:desk, {l, d}, rng}

        u < 0.8 ->
          {l, rng} = uniform_int(rng, 18, 40)
          {d, rng} = uniform_int(rng, 6, 9)
          {:shelf, {l, d}, rng}

        true ->
          {l, rng} = uniform_int(rng, 10, 18)
          {d, rng} = uniform_int(rng, 10, 14)
          {:cabinet, {l, d}, rng}
      end

    {turn, rng} = :rand.uniform_s(rng)
    {w, h} = if turn < 0.5, do: {a, b}, else: {b, a}
    {side, rng} = uniform_int(rng, 0, 4)
    {fx, rng} = :rand.uniform_s(rng)
    {fy, rng} = :rand.uniform_s(rng)

    if x1 - x0 < w or y1 - y0 < h do
      {nil, rng}
    else
      px = x0 + floor(fx * (x1 - x0 - w + 1))
      py = y0 + floor(fy * (y1 - y0 - h + 1))

      # shelves and most desks stand against a wall; pillars in the open
      {px, py} =
        case {kind, side} do
          {:pillar, _} -> {px, py}
          {_, 0} -> {x0, py}
          {_, 1} -> {x1 - w, py}
          {_, 2} -> {px, y0}
          {_, 3} -> {px, y1 - h}
          {:shelf, _} -> {x0, py}
          _ -> {px, py}
        end

      {%{kind: kind, cells: {px, py, px + w, py + h}}, rng}
    end
  end

  # flush against a wall or a gap to it, a gap to other furniture, clear of doors
  defp fits?({px0, py0, px1, py1} = cells, {x0, y0, x1, y1}, zones, placed) do
    gaps = [px0 - x0, x1 - px1, py0 - y0, y1 - py1]

    Enum.all?(gaps, &(&1 == 0 or &1 >= @gap)) and
      not Enum.any?(zones, &overlap?(&1, cells)) and
      Enum.all?(placed, fn %{cells: other} -> gap(other, cells) >= @gap end)
  end

  defp overlap?({ax0, ay0, ax1, ay1}, {bx0, by0, bx1, by1}),
    do: ax0 < bx1 and bx0 < ax1 and ay0 < by1 and by0 < ay1

  # the larger of the x and y gaps between two rectangles (cells)
  defp gap({ax0, ay0, ax1, ay1}, {bx0, by0, bx1, by1}),
    do: max(max(bx0 - ax1, ax0 - bx1), max(by0 - ay1, ay0 - by1))

  ## Start

  # the middle of the first corridor, or of the first room clear of furniture
  defp start_point([{x0, y0, x1, y1} | _], _rooms, _doors),
    do: {(x0 + x1) / 2 * @res, (y0 + y1) / 2 * @res}

  defp start_point([], [{_, {x0, y0, x1, y1}} | _], [door | _]) do
    # beside the room's first door, inside the room
    {dx, dy} = door.at
    cx = min(max(dx / @res, x0 + 20), x1 - 20)
    cy = min(max(dy / @res, y0 + 20), y1 - 20)
    {cx * @res, cy * @res}
  end

  defp start_point([], [{_, {x0, y0, x1, y1}} | _], []),
    do: {(x0 + x1) / 2 * @res, (y0 + y1) / 2 * @res}

  defp uniform_int(rng, lo, hi) when hi <= lo, do: {lo, rng}

  defp uniform_int(rng, lo, hi) do
    {k, rng} = :rand.uniform_s(hi - lo + 1, rng)
    {lo + k - 1, rng}
  end
end
