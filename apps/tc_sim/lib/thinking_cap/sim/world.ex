defmodule ThinkingCap.Sim.World do
  @moduledoc """
  A simulated world built from a WDF (`ThinkingCap.Config.WDF`): its wall
  segments, its doors (closed doors are segments between their jambs,
  switched on and off while running), its occupancy map if it imports one,
  its beacons and its named places, behind one ray-casting world of
  `ThinkingCap.Sim.Raycast`. The ray-casting world also holds the robots'
  bodies and the doors' states: a built world belongs to one simulation
  at a time (build another for another simulation).
  """

  alias ThinkingCap.Config.{RosMap, WDF}
  alias ThinkingCap.Sim.Raycast

  @enforce_keys [:name, :raycast]
  defstruct [:name, :raycast, :bounds, doors: %{}, beacons: [], waypoints: %{}, wdf: nil]

  @type point :: {float(), float()}
  @type pose :: {float(), float(), float()}
  @type t :: %__MODULE__{
          name: String.t(),
          raycast: Raycast.world(),
          bounds: {point(), point()} | nil,
          doors: %{atom() => %{segment: non_neg_integer(), open: boolean()}},
          beacons: [%{name: atom(), at: point()}],
          waypoints: %{atom() => point() | pose()},
          wdf: WDF.t() | nil
        }

  @doc "Reads a WDF file and builds its world."
  @spec load(Path.t()) :: {:ok, t()} | {:error, String.t()}
  def load(path) do
    case ThinkingCap.Config.read(path) do
      {:ok, %WDF{} = wdf} -> from_wdf(wdf)
      {:ok, _other} -> {:error, "#{path} is not a WDF"}
      {:error, errors} -> {:error, ThinkingCap.Config.format_errors(errors)}
    end
  end

  @doc "Builds the world of a WDF."
  @spec from_wdf(WDF.t()) :: {:ok, t()} | {:error, String.t()}
  def from_wdf(%WDF{} = wdf) do
    walls = Enum.map(wdf.walls, &float_segment/1) ++ Enum.flat_map(wdf.obstacles, &edges/1)
    door_segments = Enum.map(wdf.doors, &float_segment({&1.from, &1.to}))

    with {:ok, raycast} <- Raycast.new(segments: walls ++ door_segments, grid: wdf.grid) do
      doors =
        wdf.doors
        |> Enum.with_index(length(walls))
        |> Map.new(fn {door, id} ->
          :ok = Raycast.set_segment(raycast, id, not door.open)
          {door.name, %{segment: id, open: door.open}}
        end)

      {:ok,
       %__MODULE__{
         name: wdf.name,
         raycast: raycast,
         bounds: bounds(walls ++ door_segments, wdf.grid),
         doors: doors,
         beacons: Enum.map(wdf.beacons, &%{name: &1.name, at: float_point(&1.at)}),
         waypoints: Map.new(wdf.waypoints, &{&1.name, &1.at}),
         wdf: wdf
       }}
    end
  end

  @doc "Opens (`true`) or closes (`false`) a door while running."
  @spec set_door(t(), atom(), boolean()) :: {:ok, t()} | {:error, String.t()}
  def set_door(%__MODULE__{doors: doors} = world, name, open?) when is_boolean(open?) do
    case doors do
      %{^name => door} ->
        :ok = Raycast.set_segment(world.raycast, door.segment, not open?)
        {:ok, put_in(world.doors[name].open, open?)}

      _ ->
        {:error, "no door #{inspect(name)} in world #{inspect(world.name)}"}
    end
  end

  @doc """
  A pose given as `{x, y}`, `{x, y, theta}` or the name of a waypoint of
  the world.
  """
  @spec resolve_pose(t(), atom() | point() | pose()) :: {:ok, pose()} | {:error, String.t()}
  def resolve_pose(%__MODULE__{} = world, at) do
    case at do
      {x, y, th} when is_number(x) and is_number(y) and is_number(th) ->
        {:ok, {x * 1.0, y * 1.0, th * 1.0}}

      {x, y} when is_number(x) and is_number(y) ->
        {:ok, {x * 1.0, y * 1.0, 0.0}}

      name when is_atom(name) ->
        case Map.fetch(world.waypoints, name) do
          {:ok, pose} -> resolve_pose(world, pose)
          :error -> {:error, "no waypoint #{inspect(name)} in world #{inspect(world.name)}"}
        end

      other ->
        {:error, "#{inspect(other)} is not a pose, a point or a waypoint name"}
    end
  end

  @doc """
  A pose drawn uniformly within the world's bounds (any heading), and
  the next state of `rng` (`:rand` state): the start of a search for a
  free place, with `known_free?/2` and `free?/3`. The origin for a world
  without bounds.
  """
  @spec random_pose(t(), :rand.state()) :: {{float(), float(), float()}, :rand.state()}
  def random_pose(%__MODULE__{bounds: nil}, rng), do: {{0.0, 0.0, 0.0}, rng}

  def random_pose(%__MODULE__{bounds: {{x0, y0}, {x1, y1}}}, rng) do
    {u, rng} = :rand.uniform_s(rng)
    {v, rng} = :rand.uniform_s(rng)
    {w, rng} = :rand.uniform_s(rng)
    {{x0 + u * (x1 - x0), y0 + v * (y1 - y0), (w - 0.5) * 2 * :math.pi()}, rng}
  end

  @doc """
  Whether `{x, y}` lies in a cell the world's map knows to be free
  (`true` for a world without a map): a map's unknown outside is not a
  place to put a robot.
  """
  @spec known_free?(t(), point()) :: boolean()
  def known_free?(%__MODULE__{wdf: %WDF{grid: grid}}, {x, y}) when grid != nil do
    {ox, oy, _} = grid.origin
    col = floor((x - ox) / grid.resolution)
    row = floor((y - oy) / grid.resolution)

    col >= 0 and row >= 0 and col < grid.width and row < grid.height and
      RosMap.cell(grid, col, row) == 0
  end

  def known_free?(%__MODULE__{}, _point), do: true

  @doc """
  Whether a disc of `radius` at `{x, y}` touches nothing (other robots
  included) and is not inside an obstacle.
  """
  @spec free?(t(), point(), float(), integer()) :: boolean()
  def free?(%__MODULE__{raycast: rc} = world, {x, y}, radius, exclude \\ -1) do
    Raycast.clearance(rc, x * 1.0, y * 1.0, exclude, radius * 2.0) >= radius and
      not Enum.any?(obstacles(world), &inside?(&1.polygon, {x, y}))
  end

  defp obstacles(%__MODULE__{wdf: %WDF{obstacles: obstacles}}), do: obstacles
  defp obstacles(_world), do: []

  # even-odd rule
  defp inside?(polygon, {x, y}) do
    polygon
    |> Enum.zip(tl(polygon) ++ [hd(polygon)])
    |> Enum.count(fn {{x1, y1}, {x2, y2}} ->
      y1 > y != y2 > y and x < (x2 - x1) * (y - y1) / (y2 - y1) + x1
    end)
    |> rem(2) == 1
  end

  # an obstacle's outline, closed
  defp edges(%{polygon: points}) do
    points = Enum.map(points, &float_point/1)
    Enum.zip(points, tl(points) ++ [hd(points)])
  end

  defp float_segment({a, b}), do: {float_point(a), float_point(b)}
  defp float_point({x, y}), do: {x * 1.0, y * 1.0}

  defp bounds([], nil), do: nil

  defp bounds(segments, grid) do
    points = Enum.flat_map(segments, fn {a, b} -> [a, b] end) ++ grid_corners(grid)
    {xs, ys} = Enum.unzip(points)
    {{Enum.min(xs), Enum.min(ys)}, {Enum.max(xs), Enum.max(ys)}}
  end

  defp grid_corners(nil), do: []

  defp grid_corners(%{width: w, height: h, resolution: r, origin: {ox, oy, yaw}}) do
    {c, s} = {:math.cos(yaw), :math.sin(yaw)}

    for {u, v} <- [{0, 0}, {w * r, 0}, {0, h * r}, {w * r, h * r}],
        do: {ox + c * u - s * v, oy + s * u + c * v}
  end
end
