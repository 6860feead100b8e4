defmodule ThinkingCap.Perception.Fusion do
  @moduledoc """
  Sensor fusion into the Local Perceptual Space, as pure functions (the
  module `ThinkingCap.Perception.Fuser` runs them on the blackboard's
  readings).

  Evidence is kept per cell of a fine grid (`resolution`, default 0.1 m) in
  the **odometry frame**, so it stays geometrically consistent as the
  robot moves (odometry-compensated), and only for cells within `window`
  metres of the robot. Each cell carries two fuzzy degrees:

    * **occupied**: raised by an echo in the cell (a laser hit to 0.9, the
      axis of a sonar cone to 0.6: sonar is less sure where in its cone the
      echo came from);
    * **empty**: raised to 0.9 when a later reading passes beyond the cell
      in its direction (it saw through it); a new hit lowers it again.

  A cell counts as an obstacle to the degree occupied ∧ ¬empty
  (min(o, 1 − e)). Evidence not refreshed for `memory` seconds is
  forgotten, so moving obstacles fade. The LPS (`ThinkingCap.Perception.LPS`)
  is made from the cells whose obstacle degree is at least 0.5, in the
  robot's current frame: the nearest obstacle per sector, straight
  segments fitted to them, and door openings between segment ends.
  A priori knowledge joins when a world pose is known (`put_world_pose/2`):
  the WDF's walls and doors near the robot are added as segments and doors.
  """

  alias ThinkingCap.Perception.LPS

  import ThinkingCap.Geometry,
    only: [compose: 2, normalize_angle: 1, relative: 2, segment_distance: 3, to_frame: 2]

  defstruct resolution: 0.1,
            window: 6.0,
            memory: 3.0,
            range: 5.0,
            sensors: %{},
            odom: nil,
            time: 0.0,
            cells: %{},
            world_pose: nil,
            walls: [],
            doors: [],
            robot: nil

  @type t :: %__MODULE__{}

  @doc """
  A fusion state. `sensors` maps each range sensor's name to its geometry
  (`%{type: :laser | :sonar, pose: {x, y, θ}, ring_radius: m, count: n,
  range: {min, max}}`, as in the RDF). Options: `resolution`, `window`,
  `memory`, `range` (of the LPS sectors), `walls` and `doors` (a priori, world
  frame: `{{x1, y1}, {x2, y2}}` and `%{centre:, width:, heading:}`), `robot`.
  """
  @spec new(map(), keyword()) :: t()
  def new(sensors, opts \\ []) do
    %__MODULE__{
      sensors: sensors,
      resolution: Keyword.get(opts, :resolution, 0.1),
      window: Keyword.get(opts, :window, 6.0),
      memory: Keyword.get(opts, :memory, 3.0),
      range: Keyword.get(opts, :range, 5.0) * 1.0,
      walls: Keyword.get(opts, :walls, []),
      doors: Keyword.get(opts, :doors, []),
      robot: opts[:robot]
    }
  end

  @doc "The robot's odometry pose (odometry frame) and the time."
  @spec put_odometry(t(), {float(), float(), float()}, float()) :: t()
  def put_odometry(state, pose, time), do: %{state | odom: pose, time: max(state.time, time)}

  @doc """
  The robot's estimated world pose (brings the a priori map in); ignored
  before the first odometry reading, which it is paired with.
  """
  @spec put_world_pose(t(), {float(), float(), float()}) :: t()
  def put_world_pose(%{odom: nil} = state, _pose), do: state
  def put_world_pose(state, pose), do: %{state | world_pose: {pose, state.odom}}

  @doc """
  Adds a range reading of sensor `name` (payload as published by a robot:
  `ranges` with `angle_min`/`angle_increment` for a laser, `headings` for a
  sonar ring).
  """
  @spec add_reading(t(), atom(), map()) :: t()
  def add_reading(%{odom: nil} = state, _name, _payload), do: state

  def add_reading(state, name, %{ranges: ranges} = payload) do
    case Map.fetch(state.sensors, name) do
      {:ok, sensor} ->
        time = Map.get(payload, :stamp, state.time)
        rays = rays(sensor, payload, ranges, state.odom)
        state = %{state | time: max(state.time, time)}
        state |> see_through(rays, sensor) |> hits(rays, sensor.type) |> forget()

      :error ->
        state
    end
  end

  def add_reading(state, _name, _payload), do: state

  # Each reading as a ray in the odometry frame:
  # {ox, oy, angle, range, max_range, hit?}
  defp rays(%{type: :laser} = s, payload, ranges, odom) do
    {sx, sy, sth} = s.pose
    {_min, max} = s.range
    {ox, oy, a0} = compose(odom, {sx, sy, sth})
    inc = Map.get(payload, :angle_increment, 0.0)
    amin = Map.get(payload, :angle_min, 0.0)

    ranges
    |> Enum.with_index()
    |> Enum.map(fn {r, i} -> {ox, oy, a0 + amin + i * inc, r, max, r < max - 1.0e-6} end)
  end

  defp rays(%{type: :sonar} = s, payload, ranges, odom) do
    {px, py, _} = s.pose
    {_min, max} = s.range
    headings = Map.get(payload, :headings) || ring_headings(s)

    Enum.zip(headings, ranges)
    |> Enum.map(fn {h, r} ->
      local = {px + s.ring_radius * :math.cos(h), py + s.ring_radius * :math.sin(h), h}
      {ox, oy, a} = compose(odom, local)
      {ox, oy, a, r, max, r < max - 1.0e-6}
    end)
  end

  defp ring_headings(%{count: n, pose: {_, _, th}}),
    do: for(i <- 0..(n - 1), do: th + 2 * :math.pi() * i / n)

  # Cells the new rays pass beyond gain "empty". The rays of one reading are
  # evenly spread in angle, so each cell is checked against the ray
  # nearest its bearing (seen from the robot) and that ray's neighbours.
  defp see_through(state, rays, sensor) do
    res = state.resolution
    index = List.to_tuple(rays)
    n = tuple_size(index)
    {x, y, _} = state.odom
    {_, _, a0, _, _, _} = elem(index, 0)
    {inc, wrap?} = spacing(sensor, index)
    half = if sensor.type == :sonar, do: :math.tan(Map.get(sensor, :fov, 0.26) / 2), else: 0.0

    cells =
      Map.new(state.cells, fn {key, {o, e, t} = ev} ->
        {cx, cy} = cell_centre(key, res)
        i = round(normalize_angle(:math.atan2(cy - y, cx - x) - a0) / inc)

        seen =
          Enum.any?([i - 1, i, i + 1], fn k ->
            k = if wrap?, do: Integer.mod(k, n), else: k
            k >= 0 and k < n and beyond?(elem(index, k), cx, cy, res, half)
          end)

        if seen, do: {key, {o, max(e, 0.9), t}}, else: {key, ev}
      end)

    %{state | cells: cells}
  end

  defp spacing(%{type: :sonar, count: n}, _index), do: {2 * :math.pi() / n, true}

  defp spacing(_laser, index) when tuple_size(index) > 1 do
    {_, _, a0, _, _, _} = elem(index, 0)
    {_, _, a1, _, _, _} = elem(index, 1)
    {normalize_angle(a1 - a0), false}
  end

  defp spacing(_laser, _index), do: {1.0, false}

  # does the ray (or the sonar cone, of half-width tan `half`) reach beyond
  # the cell?
  defp beyond?({ox, oy, a, r, _max, _hit}, cx, cy, res, half) do
    {dx, dy} = {cx - ox, cy - oy}
    {c, s} = {:math.cos(a), :math.sin(a)}
    along = dx * c + dy * s
    across = abs(-dx * s + dy * c)
    along > 0 and across < res * 0.5 + along * half and r > along + res * 1.5
  end

  defp hits(state, rays, type) do
    degree = if type == :laser, do: 0.9, else: 0.6

    cells =
      Enum.reduce(rays, state.cells, fn
        {ox, oy, a, r, _max, true}, cells ->
          key = cell_key({ox + r * :math.cos(a), oy + r * :math.sin(a)}, state.resolution)

          Map.update(cells, key, {degree, 0.0, state.time}, fn {o, e, _t} ->
            {max(o, degree), min(e, 0.2), state.time}
          end)

        _miss, cells ->
          cells
      end)

    %{state | cells: cells}
  end

  defp forget(%{odom: {x, y, _}} = state) do
    w2 = state.window * state.window
    res = state.resolution

    cells =
      for {key, {_o, _e, t} = ev} <- state.cells,
          state.time - t <= state.memory,
          {cx, cy} = cell_centre(key, res),
          (cx - x) * (cx - x) + (cy - y) * (cy - y) <= w2,
          into: %{},
          do: {key, ev}

    %{state | cells: cells}
  end

  @doc "The LPS now, in the robot's current frame."
  @spec lps(t()) :: LPS.t()
  def lps(%{odom: nil} = state), do: LPS.empty(range: state.range, robot: state.robot)

  def lps(state) do
    {x, y, th} = state.odom
    {c, s} = {:math.cos(th), :math.sin(th)}
    res = state.resolution

    evidence =
      for {key, {o, e, _t}} <- state.cells do
        {cx, cy} = cell_centre(key, res)
        {dx, dy} = {cx - x, cy - y}
        {c * dx + s * dy, -s * dx + c * dy, o, e}
      end

    obstacles = for {px, py, o, e} <- evidence, min(o, 1 - e) >= 0.5, do: {px, py}
    lps = LPS.from_points(obstacles, range: state.range, robot: state.robot)
    segments = ThinkingCap.Perception.Lines.fit(obstacles, res * 1.5)
    {map_walls, map_doors} = a_priori(state)

    %{
      lps
      | stamp: state.time,
        pose: state.odom,
        evidence: evidence,
        segments: segments ++ map_walls,
        doors: map_doors ++ ThinkingCap.Perception.Lines.openings(segments, state.range)
    }
  end

  # the WDF's walls and doors near the robot, in its frame, through the
  # world pose (corrected for the odometry travelled since it came)
  defp a_priori(%{world_pose: nil}), do: {[], []}

  defp a_priori(%{world_pose: {world, odom_then}, odom: odom_now} = state) do
    {x, y, _} = pose = compose(world, relative(odom_then, odom_now))
    near = state.range + 1.0

    walls =
      for {a, b} <- state.walls,
          segment_distance({x, y}, a, b) <= near,
          do: {to_frame(pose, a), to_frame(pose, b)}

    doors =
      for %{centre: centre} = d <- state.doors,
          distance(pose, centre) <= near do
        {_, _, th} = pose
        %{d | centre: to_frame(pose, centre), heading: normalize_angle(d.heading - th)}
      end

    {walls, doors}
  end

  ## geometry

  defp distance({x, y, _}, {px, py}), do: :math.sqrt((px - x) ** 2 + (py - y) ** 2)

  defp cell_key({x, y}, res), do: {floor(x / res), floor(y / res)}
  defp cell_centre({i, j}, res), do: {(i + 0.5) * res, (j + 0.5) * res}
end
