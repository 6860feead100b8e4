defmodule ThinkingCap.Config.WDF do
  @named_polygon [
    name: {:atom, required: true, doc: "unique name"},
    polygon: {{:list, :point}, required: true, doc: "corners, m (at least 3)"}
  ]

  @door_fields [
    name: {:atom, required: true, doc: "unique name"},
    from: {:point, required: true, doc: "one jamb, m"},
    to: {:point, required: true, doc: "the other jamb, m"},
    open:
      {:boolean,
       default: true, doc: "open at start (doors can be opened and closed while running)"},
    connects: {{:list, :atom}, default: [], doc: "the rooms or corridors it joins"}
  ]

  @beacon_fields [
    name: {:atom, required: true, doc: "unique name"},
    at: {:point, required: true, doc: "position, m"}
  ]

  @area_fields [
    name: {:atom, required: true, doc: "unique name"},
    polygon: {{:list, :point}, required: true, doc: "corners, m (at least 3)"},
    kind: {:atom, default: :area, doc: "what the area is for (`:charging`, `:forbidden`, ...)"}
  ]

  @waypoint_fields [
    name: {:atom, required: true, doc: "unique name"},
    at: {:point_or_pose, required: true, doc: "{x, y} or {x, y, theta}"}
  ]

  @crowd_fields [
    count: {:non_neg_integer, required: true, doc: "how many walkers"},
    seed: {:integer, default: 1, doc: "their routes and speeds are drawn from it"},
    points: {{:int_range, 2, 100}, default: 3, doc: "points of a route"},
    reach: {:pos_number, default: 10.0, doc: "the longest leg of a route, m"},
    speed: {:range, default: {0.6, 1.2}, doc: "walking speeds, m/s, each walker's drawn between"},
    radius: {:pos_number, default: 0.25, doc: "a walker's radius, m"}
  ]

  @map_fields [
    yaml: {:path, required: true, doc: "a ROS map_server YAML file, relative to this file"}
  ]

  @fields [
    name: {:string, required: true, doc: "the world"},
    map: {{:keyword, @map_fields}, doc: "an occupancy map to import (below)"},
    walls: {{:list, :segment}, default: [], doc: "wall segments"},
    obstacles:
      {{:list, {:keyword, @named_polygon}},
       default: [], doc: "solid obstacles (shelves, pillars): name, polygon"},
    rooms: {{:list, {:keyword, @named_polygon}}, default: [], doc: "rooms (name, polygon)"},
    corridors:
      {{:list, {:keyword, @named_polygon}}, default: [], doc: "corridors (name, polygon)"},
    doors: {{:list, {:keyword, @door_fields}}, default: [], doc: "doors (below)"},
    beacons:
      {{:list, {:keyword, @beacon_fields}},
       default: [], doc: "reflective beacons for laser localization"},
    areas: {{:list, {:keyword, @area_fields}}, default: [], doc: "named areas (below)"},
    waypoints: {{:list, {:keyword, @waypoint_fields}}, default: [], doc: "named places (below)"},
    crowd:
      {{:keyword, @crowd_fields},
       doc: "people walking back and forth in free space, drawn from a seed (below)"}
  ]

  @moduledoc """
  The world description file (`*.wdf`): walls, obstacles, rooms,
  corridors, doors, beacons, areas and waypoints, and optionally an
  occupancy map imported from a ROS `map_server` YAML + PGM pair
  (`ThinkingCap.Config.RosMap`). A world may be empty (`[name: "empty"]`).

  ## Top-level keys

  #{ThinkingCap.Config.Schema.describe(@fields)}

  ## Door keys

  #{ThinkingCap.Config.Schema.describe(@door_fields)}

  ## Area keys

  #{ThinkingCap.Config.Schema.describe(@area_fields)}

  ## Waypoint keys

  #{ThinkingCap.Config.Schema.describe(@waypoint_fields)}

  ## Map keys

  #{ThinkingCap.Config.Schema.describe(@map_fields)}

  ## Crowd keys

  The simulator (`ThinkingCap.Sim.Crowd`) draws the walkers' routes (in
  known-free space, every leg clear of walls) and speeds from the seed:
  the same file walks the same crowd.

  #{ThinkingCap.Config.Schema.describe(@crowd_fields)}
  """

  alias ThinkingCap.Config.{RosMap, Schema}

  defstruct [
    :file,
    :name,
    :grid,
    :crowd,
    walls: [],
    obstacles: [],
    rooms: [],
    corridors: [],
    doors: [],
    beacons: [],
    areas: [],
    waypoints: []
  ]

  @type t :: %__MODULE__{
          file: Path.t(),
          name: String.t(),
          grid: RosMap.t() | nil,
          crowd: map() | nil,
          walls: [{{float(), float()}, {float(), float()}}],
          obstacles: [map()],
          rooms: [map()],
          corridors: [map()],
          doors: [map()],
          beacons: [map()],
          areas: [map()],
          waypoints: [map()]
        }

  @named [:obstacles, :rooms, :corridors, :doors, :beacons, :areas, :waypoints]

  @doc """
  Whether a world says nothing of its geometry: no walls, obstacles, rooms,
  corridors, doors or occupancy map (beacons, areas and waypoints may be
  given). A robot in such a world starts from what it senses.
  """
  @spec empty?(t()) :: boolean()
  def empty?(%__MODULE__{} = wdf) do
    wdf.grid == nil and
      Enum.all?([wdf.walls, wdf.obstacles, wdf.rooms, wdf.corridors, wdf.doors], &(&1 == []))
  end

  @doc false
  @spec from_data(term(), Path.t(), map()) ::
          {:ok, t()} | {:error, [ThinkingCap.Config.Error.t()]}
  def from_data(data, file, positions) do
    {value, st} = Schema.start(data, @fields, file, positions)
    st = st |> check_names(value) |> check_polygons(value) |> check_doors(value)
    {grid, st} = load_map(st, value[:map])

    case Schema.errors(st) do
      [] ->
        {:ok,
         struct!(
           __MODULE__,
           value
           |> Map.take([:name, :walls, :crowd | @named])
           |> Map.merge(%{file: file, grid: grid})
         )}

      errors ->
        {:error, errors}
    end
  end

  # The cross-checks below look only at items whose own fields passed:
  # a field that failed is reported already, and is missing here.
  defp check_names(st, value) do
    {st, _} =
      for key <- @named,
          {item, i} <- Enum.with_index(value[key] || []),
          Map.has_key?(item, :name),
          reduce: {st, %{}} do
        {st, seen} ->
          case Map.fetch(seen, item.name) do
            {:ok, {other, j}} ->
              message =
                "#{key}[#{i}].name: #{inspect(item.name)} is already the name of #{other}[#{j}]"

              {Schema.error(st, [key, i, :name], message), seen}

            :error ->
              {st, Map.put(seen, item.name, {key, i})}
          end
      end

    st
  end

  defp check_polygons(st, value) do
    for key <- [:obstacles, :rooms, :corridors, :areas],
        {item, i} <- Enum.with_index(value[key] || []),
        length(Map.get(item, :polygon, [])) in 1..2,
        reduce: st do
      st -> Schema.error(st, [key, i, :polygon], "#{key}[#{i}].polygon: needs at least 3 points")
    end
  end

  defp check_doors(st, value) do
    places =
      MapSet.new(
        Enum.map((value[:rooms] || []) ++ (value[:corridors] || []), &Map.get(&1, :name))
      )

    for {door, i} <- Enum.with_index(value[:doors] || []),
        {place, j} <- Enum.with_index(Map.get(door, :connects, [])),
        not MapSet.member?(places, place),
        reduce: st do
      st ->
        Schema.error(
          st,
          [:doors, i, :connects, j],
          "doors[#{i}].connects: #{inspect(place)} is not a room or corridor of this world"
        )
    end
  end

  defp load_map(st, nil), do: {nil, st}
  defp load_map(st, %{yaml: nil}), do: {nil, st}

  defp load_map(st, %{yaml: yaml}) do
    # a name the schema refused (reported already) is not opened
    if Schema.file_name?(yaml), do: read_map(st, yaml), else: {nil, st}
  end

  defp read_map(st, yaml) do
    case RosMap.load(Path.expand(yaml, Path.dirname(st.file))) do
      {:ok, grid} ->
        {grid, st}

      {:error, errors} ->
        st = Schema.error(st, [:map, :yaml], "map.yaml: the map #{inspect(yaml)} is refused:")
        {nil, %{st | errors: Enum.reverse(errors, st.errors)}}
    end
  end
end
