defmodule ThinkingCap.Navigation.Topology do
  @moduledoc """
  The topological map of a world: its **places** (the WDF's rooms and
  corridors, each with its polygon and centroid) joined by its **doors**.

  A door joins the places its `connects:` names (every pair of them, when
  it names more than two). A door with `connects: []` joins the two places
  nearest its centre on either side of it: probes a little way from the
  centre along the door's normal, each taken by the place whose polygon
  contains it or is nearest to it; a door that finds one place only joins
  nothing.

  `route/4` searches the doors (Dijkstra) for the shortest way from place
  to place, the cost being the length of the polyline from the start point
  (the start place's centroid, or a given point) through the centres of the
  doors crossed to the goal point: walking across a long corridor from one
  door to the next costs the distance between those doors, not a detour by
  the corridor's centroid.
  """

  alias ThinkingCap.Config.WDF

  defstruct places: %{}, doors: %{}

  @type point :: {float(), float()}
  @type place :: %{name: atom(), kind: :room | :corridor, polygon: [point()], centroid: point()}
  @type door :: %{
          name: atom(),
          centre: point(),
          connects: [atom()],
          open: boolean(),
          from: point(),
          to: point()
        }
  @type t :: %__MODULE__{places: %{atom() => place()}, doors: %{atom() => door()}}
  @type step :: %{place: atom(), via_door: atom() | nil, point: point()}

  # how far from a door's centre the probes for its places go, m
  @probe 0.25

  @doc "The topological map of a world description."
  @spec from_wdf(WDF.t()) :: t()
  def from_wdf(%WDF{} = wdf) do
    places =
      for {kind, list} <- [room: wdf.rooms, corridor: wdf.corridors],
          %{name: name, polygon: polygon} <- list,
          into: %{} do
        {name, %{name: name, kind: kind, polygon: polygon, centroid: centroid(polygon)}}
      end

    doors =
      for door <- wdf.doors, into: %{} do
        {fx, fy} = door.from
        {tx, ty} = door.to
        centre = {(fx + tx) / 2, (fy + ty) / 2}
        connects = if door.connects == [], do: infer(places, door, centre), else: door.connects

        {door.name,
         %{
           name: door.name,
           centre: centre,
           connects: connects,
           open: door.open,
           from: door.from,
           to: door.to
         }}
      end

    %__MODULE__{places: places, doors: doors}
  end

  @doc """
  The place containing a point (rooms before corridors, then by name, when
  polygons overlap); outside every polygon, the place with the nearest
  centroid; `nil` for a map without places.
  """
  @spec place_of(t(), {number(), number()}) :: atom() | nil
  def place_of(%__MODULE__{places: places}, point) do
    ordered = places |> Map.values() |> Enum.sort_by(&{&1.kind != :room, &1.name})

    case Enum.find(ordered, &inside?(point, &1.polygon)) do
      %{name: name} ->
        name

      nil when ordered == [] ->
        nil

      nil ->
        Enum.min_by(ordered, &dist(point, &1.centroid)).name
    end
  end

  @doc "The places a place is joined to by open doors (`closed:` as in `route/4`), with the doors."
  @spec neighbours(t(), atom(), keyword()) :: [{atom(), atom()}]
  def neighbours(%__MODULE__{} = topo, place, opts \\ []) do
    for door <- usable_doors(topo, opts),
        place in door.connects,
        other <- door.connects,
        other != place,
        do: {other, door.name}
  end

  @doc """
  The shortest route between two places (names, or points `{x, y}` placed
  with `place_of/2`). Options:

    * `closed` - doors that cannot be crossed (default: the doors of the
      WDF that are closed at start, `open: false`; `closed: []` treats
      every door as open);
    * `from_point`, `to_point` - where the route starts and ends (default:
      the given points, else the places' centroids).

  Returns `{:ok, steps}`: the first step is the start
  (`%{place: from, via_door: nil, point: start}`), each further step the
  crossing of a door into a place (`%{place: p, via_door: door, point:
  door_centre}`); or `{:error, :no_route}` (also for an unknown place).
  """
  @spec route(t(), atom() | point(), atom() | point(), keyword()) ::
          {:ok, [step()]} | {:error, :no_route}
  def route(%__MODULE__{} = topo, from, to, opts \\ []) do
    {from, from_point} = endpoint(topo, from, Keyword.get(opts, :from_point))
    {to, to_point} = endpoint(topo, to, Keyword.get(opts, :to_point))

    cond do
      from == nil or to == nil ->
        {:error, :no_route}

      from == to ->
        {:ok, [%{place: from, via_door: nil, point: from_point}]}

      true ->
        doors = usable_doors(topo, opts)
        start = %{place: from, via_door: nil, point: from_point}

        case dijkstra(
               doors,
               to,
               to_point,
               :gb_sets.singleton({0.0, from, nil, from_point, [start]}),
               MapSet.new()
             ) do
          nil -> {:error, :no_route}
          steps -> {:ok, steps}
        end
    end
  end

  ## search: states are {place entered, door entered by}

  defp dijkstra(doors, goal, goal_point, queue, done) do
    if :gb_sets.is_empty(queue) do
      nil
    else
      {{cost, place, via, point, steps}, queue} = :gb_sets.take_smallest(queue)

      cond do
        place == goal and via == :goal ->
          Enum.reverse(steps)

        MapSet.member?(done, {place, via}) ->
          dijkstra(doors, goal, goal_point, queue, done)

        true ->
          done = MapSet.put(done, {place, via})

          queue =
            if place == goal,
              do:
                :gb_sets.add(
                  {cost + dist(point, goal_point), place, :goal, goal_point, steps},
                  queue
                ),
              else: queue

          queue =
            for door <- doors,
                door.name != via,
                place in door.connects,
                next <- door.connects,
                next != place,
                not MapSet.member?(done, {next, door.name}),
                reduce: queue do
              queue ->
                step = %{place: next, via_door: door.name, point: door.centre}

                :gb_sets.add(
                  {cost + dist(point, door.centre), next, door.name, door.centre, [step | steps]},
                  queue
                )
            end

          dijkstra(doors, goal, goal_point, queue, done)
      end
    end
  end

  defp endpoint(topo, {x, y} = point, given) do
    {place_of(topo, point), given || {x * 1.0, y * 1.0}}
  end

  defp endpoint(%__MODULE__{places: places}, name, given) do
    case Map.fetch(places, name) do
      {:ok, place} -> {name, given || place.centroid}
      :error -> {nil, nil}
    end
  end

  defp usable_doors(%__MODULE__{doors: doors}, opts) do
    closed =
      case Keyword.fetch(opts, :closed) do
        {:ok, names} -> MapSet.new(names)
        :error -> doors |> Map.values() |> Enum.reject(& &1.open) |> MapSet.new(& &1.name)
      end

    doors
    |> Map.values()
    |> Enum.reject(&MapSet.member?(closed, &1.name))
    |> Enum.sort_by(& &1.name)
  end

  ## geometry

  defp infer(places, %{from: {fx, fy}, to: {tx, ty}}, {cx, cy}) do
    len = :math.sqrt((tx - fx) ** 2 + (ty - fy) ** 2)

    if len == 0 or map_size(places) < 2 do
      []
    else
      {nx, ny} = {-(ty - fy) / len, (tx - fx) / len}

      ranked = fn probe ->
        places |> Map.values() |> Enum.sort_by(&{polygon_distance(probe, &1.polygon), &1.name})
      end

      [a | _] = ranked.({cx + @probe * nx, cy + @probe * ny})
      b = Enum.find(ranked.({cx - @probe * nx, cy - @probe * ny}), &(&1.name != a.name))

      if b &&
           polygon_distance({cx, cy}, b.polygon) <=
             2 * @probe + polygon_distance({cx, cy}, a.polygon),
         do: [a.name, b.name],
         else: []
    end
  end

  defp polygon_distance(point, polygon) do
    if inside?(point, polygon) do
      0.0
    else
      polygon
      |> Enum.zip(tl(polygon) ++ [hd(polygon)])
      |> Enum.map(&ThinkingCap.Navigation.Maps.Segments.distance(point, &1))
      |> Enum.min()
    end
  end

  # even-odd rule; points on the boundary count as inside
  defp inside?({px, py} = point, polygon) do
    edges = Enum.zip(polygon, tl(polygon) ++ [hd(polygon)])

    Enum.any?(edges, &(ThinkingCap.Navigation.Maps.Segments.distance(point, &1) < 1.0e-9)) or
      Enum.reduce(edges, false, fn {{x1, y1}, {x2, y2}}, inside ->
        if y1 > py != y2 > py and px < (x2 - x1) * (py - y1) / (y2 - y1) + x1,
          do: not inside,
          else: inside
      end)
  end

  # the area centroid (the vertex mean for a degenerate polygon)
  defp centroid(polygon) do
    edges = Enum.zip(polygon, tl(polygon) ++ [hd(polygon)])

    {a, cx, cy} =
      Enum.reduce(edges, {0.0, 0.0, 0.0}, fn {{x1, y1}, {x2, y2}}, {a, cx, cy} ->
        cross = x1 * y2 - x2 * y1
        {a + cross, cx + (x1 + x2) * cross, cy + (y1 + y2) * cross}
      end)

    if abs(a) < 1.0e-12 do
      {xs, ys} = Enum.unzip(polygon)
      {Enum.sum(xs) / length(xs), Enum.sum(ys) / length(ys)}
    else
      {cx / (3 * a), cy / (3 * a)}
    end
  end

  defp dist({x1, y1}, {x2, y2}), do: :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)
end
