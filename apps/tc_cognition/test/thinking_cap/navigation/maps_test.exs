defmodule ThinkingCap.Navigation.MapsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.{RosMap, WDF}
  alias ThinkingCap.Navigation.{Grid, Maps}
  alias ThinkingCap.Navigation.Maps.{FuzzyGrid, LogOdds, Segments}

  @office Path.expand("../../../../../priv/examples/office.wdf", __DIR__)

  defp blocked(grid) do
    for r <- 0..(grid.height - 1),
        c <- 0..(grid.width - 1),
        not Grid.passable?(grid, {c, r}),
        into: MapSet.new(),
        do: {c, r}
  end

  defp box(extra \\ []) do
    walls = [
      {{0.0, 0.0}, {2.0, 0.0}},
      {{2.0, 0.0}, {2.0, 2.0}},
      {{2.0, 2.0}, {0.0, 2.0}},
      {{0.0, 2.0}, {0.0, 0.0}}
    ]

    struct!(%WDF{name: "box", walls: walls}, extra)
  end

  describe "grid_from_wdf/2" do
    test "a box: exactly the cells on its walls are blocked" do
      grid = Maps.grid_from_wdf(box(), resolution: 0.1)
      assert {grid.width, grid.height} == {30, 30}
      {ox, oy} = grid.origin
      assert_in_delta ox, -0.5, 1.0e-9
      assert_in_delta oy, -0.5, 1.0e-9

      # the walls lie on cell boundaries (x = 0 is between columns 4 and 5):
      # both cells they touch are blocked
      on_wall = [4, 5, 24, 25]

      expected =
        for c <- 4..25, r <- 4..25, c in on_wall or r in on_wall, into: MapSet.new(), do: {c, r}

      assert blocked(grid) == expected
    end

    test "walls off the cell boundaries block the cells they cross, and only those" do
      rng = :rand.seed_s(:exsss, 5)

      Enum.reduce(1..30, rng, fn _, rng ->
        {[x1, y1, x2, y2], rng} =
          Enum.map_reduce(1..4, rng, fn _, rng -> :rand.uniform_s(rng) end)

        wall = {{x1 * 3, y1 * 3}, {x2 * 3, y2 * 3}}

        grid =
          Maps.grid_from_wdf(%WDF{name: "w", walls: [wall]},
            resolution: 0.1,
            bounds: {{0.0, 0.0}, {3.0, 3.0}}
          )

        expected =
          for c <- 0..29,
              r <- 0..29,
              crosses?(wall, {c * 0.1, r * 0.1, 0.1}),
              into: MapSet.new(),
              do: {c, r}

        assert blocked(grid) == expected
        rng
      end)
    end

    test "obstacle polygons are filled" do
      triangle = %{name: :t, polygon: [{0.2, 0.2}, {1.8, 0.2}, {1.0, 1.8}]}

      grid =
        Maps.grid_from_wdf(%WDF{name: "t", obstacles: [triangle]},
          resolution: 0.1,
          bounds: {{0.0, 0.0}, {2.0, 2.0}}
        )

      # inside
      refute Grid.passable?(grid, Grid.cell_of(grid, {1.0, 0.8}))
      refute Grid.passable?(grid, Grid.cell_of(grid, {0.5, 0.3}))
      # outside
      assert Grid.passable?(grid, Grid.cell_of(grid, {0.3, 1.5}))
      assert Grid.passable?(grid, Grid.cell_of(grid, {1.0, 1.95}))
      # about the triangle's area (1.28 m²) in 0.01 m² cells, plus its rim
      assert MapSet.size(blocked(grid)) in 128..200
    end

    test "a closed door blocks its opening, an open one leaves it exactly as wide as the door" do
      wdf = ThinkingCap.Config.read!(@office)
      grid = Maps.grid_from_wdf(wdf)
      lab_door = Enum.find(wdf.doors, &(&1.name == :lab_door))
      b_door = Enum.find(wdf.doors, &(&1.name == :b_door))

      # b_door is closed at start, lab_door open
      refute Grid.passable?(grid, Grid.cell_of(grid, {16.0, 3.0}))
      assert Grid.passable?(grid, Grid.cell_of(grid, {3.0, 3.0}))

      # lab_door's opening: x from 2.5 to 3.5 is columns 60..79 (origin −0.5, 0.05 m)
      cells = Maps.door_cells(grid, lab_door)
      assert length(cells) == 40
      assert cells |> Enum.map(&elem(&1, 0)) |> Enum.uniq() |> Enum.sort() == Enum.to_list(60..79)
      assert Enum.all?(cells, &Grid.passable?(grid, &1))
      {_, row} = hd(cells)
      refute Grid.passable?(grid, {59, row})
      refute Grid.passable?(grid, {80, row})

      # closing it blocks exactly its cells
      shut = Maps.grid_from_wdf(wdf, closed: [:lab_door, :b_door])
      assert MapSet.difference(blocked(shut), blocked(grid)) == MapSet.new(cells)

      # opening b_door frees exactly its cells
      open = Maps.grid_from_wdf(wdf, closed: [])
      assert Grid.put(grid, Maps.door_cells(grid, b_door), false) == open
    end

    test "an occupancy map: occupied and unknown cells blocked, aligned with the world" do
      # 4 × 2 cells of 0.5 m at {1, 2}; bottom row first
      data = <<0, 100, -1::signed-8, 50, 49, 0, 0, 100>>

      map = %RosMap{
        file: "m.yaml",
        width: 4,
        height: 2,
        resolution: 0.5,
        origin: {1.0, 2.0, 0.0},
        data: data
      }

      grid = Maps.grid_from_wdf(%WDF{name: "m", grid: map})
      assert {grid.width, grid.height, grid.origin, grid.resolution} == {4, 2, {1.0, 2.0}, 0.5}
      assert grid.cells == <<0, 1, 1, 1, 0, 0, 0, 1>>

      assert Maps.grid_from_wdf(%WDF{name: "m", grid: map}, unknown: :free).cells ==
               <<0, 1, 0, 1, 0, 0, 0, 1>>

      # a wall beyond the map widens the grid by whole cells, keeping the map's alignment
      wide =
        Maps.grid_from_wdf(%WDF{name: "m", grid: map, walls: [{{0.2, 2.4}, {0.2, 2.6}}]},
          margin: 0.1
        )

      assert {wide.width, wide.origin} == {6, {0.0, 2.0}}
      assert binary_part(wide.cells, 0, 6) == <<1, 0, 0, 1, 1, 1>>

      assert_raise ArgumentError, ~r/yaw of 0.3 rad/, fn ->
        Maps.grid_from_wdf(%WDF{name: "m", grid: %{map | origin: {1.0, 2.0, 0.3}}})
      end

      assert_raise ArgumentError, ~r/resampling is not supported/, fn ->
        Maps.grid_from_wdf(%WDF{name: "m", grid: map}, resolution: 0.1)
      end
    end

    @tag :tmp_dir
    test "a WDF importing a ROS map_server map", %{tmp_dir: dir} do
      # 3 × 2 pixels, top row first: black is occupied, white free, grey unknown
      File.write!(Path.join(dir, "map.pgm"), ["P5\n3 2\n255\n", <<0, 254, 254, 205, 254, 0>>])

      File.write!(
        Path.join(dir, "map.yaml"),
        "image: map.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n"
      )

      File.write!(Path.join(dir, "w.wdf"), ~s([name: "m", map: [yaml: "map.yaml"]]))

      grid = Maps.grid_from_wdf(ThinkingCap.Config.read!(Path.join(dir, "w.wdf")))
      assert {grid.width, grid.height} == {3, 2}
      # bottom row (the image's last) first
      assert grid.cells == <<1, 0, 1, 1, 0, 0>>
    end

    test "a warehouse-sized map (1006 × 1674 cells) is built and inflated" do
      {w, h} = {1006, 1674}
      # racks every 2.5 m, cross aisles every 4 m, an unexplored corner
      rack_row =
        for c <- 0..(w - 1), into: <<>>, do: if(rem(c, 50) in [0, 1], do: <<100>>, else: <<0>>)

      aisle = :binary.copy(<<100>>, w)
      unknown = binary_part(rack_row, 0, 900) <> :binary.copy(<<-1::signed-8>>, 106)

      data =
        IO.iodata_to_binary(
          for r <- 0..(h - 1) do
            cond do
              rem(r, 80) == 0 -> aisle
              r > 1500 -> unknown
              true -> rack_row
            end
          end
        )

      map = %RosMap{
        file: "warehouse.yaml",
        width: w,
        height: h,
        resolution: 0.05,
        origin: {-10.0, -5.0, 0.0},
        data: data
      }

      obstacles =
        for i <- 0..99 do
          {x, y} = {-9.0 + rem(i, 10) * 4.0, -4.0 + div(i, 10) * 8.0}

          %{
            name: :"pallet#{i}",
            polygon: [{x, y}, {x + 1.2, y}, {x + 1.2, y + 0.8}, {x, y + 0.8}]
          }
        end

      wdf = %WDF{
        name: "warehouse",
        grid: map,
        obstacles: obstacles,
        walls: [{{-10.0, -5.0}, {40.0, 60.0}}]
      }

      grid = Maps.grid_from_wdf(wdf)
      inflated = Maps.inflate(grid, 0.3)

      assert {grid.width, grid.height} == {w, h}
      refute Grid.passable?(grid, Grid.cell_of(grid, {-8.4, -3.6}))
      refute Grid.passable?(grid, {1000, 1600})
      assert Maps.blocked_count(inflated) > Maps.blocked_count(grid)
    end
  end

  # whether a segment meets the closed square [x, x + s] × [y, y + s]
  # (Liang–Barsky clipping)
  defp crosses?({{x1, y1}, {x2, y2}}, {x, y, s}) do
    {dx, dy} = {x2 - x1, y2 - y1}

    Enum.reduce_while(
      [{-dx, x1 - x}, {dx, x + s - x1}, {-dy, y1 - y}, {dy, y + s - y1}],
      {0.0, 1.0},
      fn
        {p, q}, {t0, t1} when p == 0 ->
          if q < 0, do: {:halt, nil}, else: {:cont, {t0, t1}}

        {p, q}, {t0, t1} when p < 0 ->
          t = q / p
          if t > t1, do: {:halt, nil}, else: {:cont, {max(t0, t), t1}}

        {p, q}, {t0, t1} ->
          t = q / p
          if t < t0, do: {:halt, nil}, else: {:cont, {t0, min(t1, t)}}
      end
    ) != nil
  end

  describe "prior/2" do
    @tag :tmp_dir
    test "the map's cells as it has them, the grid's blocked cells occupied", %{tmp_dir: dir} do
      File.write!(Path.join(dir, "map.pgm"), ["P5\n3 2\n255\n", <<0, 254, 254, 205, 254, 0>>])

      File.write!(
        Path.join(dir, "map.yaml"),
        "image: map.pgm\nresolution: 0.1\norigin: [0.0, 0.0, 0.0]\n"
      )

      File.write!(Path.join(dir, "w.wdf"), ~s([name: "m", map: [yaml: "map.yaml"]]))
      wdf = ThinkingCap.Config.read!(Path.join(dir, "w.wdf"))
      grid = Maps.grid_from_wdf(wdf, unknown: :free)

      # the map alone (no blocked cell), then with blocked cells where the
      # map is free and unknown (as a box would be)
      raw = Maps.prior(wdf, %{grid | cells: <<0, 0, 0, 0, 0, 0>>}).data
      assert raw == <<255, 0, 100, 100, 0, 0>>
      prior = Maps.prior(wdf, %{grid | cells: <<1, 1, 0, 1, 0, 1>>})
      assert prior.data == <<100, 100, 100, 100, 0, 100>>
      assert {prior.width, prior.height, prior.resolution} == {3, 2, 0.1}
    end
  end

  describe "inflate/2" do
    test "a single blocked cell becomes a disc of the robot's radius" do
      grid = Grid.new(21, 21, resolution: 0.05) |> Grid.put([{10, 10}], true)
      inflated = Maps.inflate(grid, 0.25)

      # a disc of 5 cells: 81 cell centres within it
      assert Maps.blocked_count(inflated) == 81

      for cell <- [{15, 10}, {10, 5}, {14, 13}, {13, 6}],
          do: refute(Grid.passable?(inflated, cell))

      for cell <- [{16, 10}, {14, 14}, {6, 6}], do: assert(Grid.passable?(inflated, cell))
      assert Maps.inflate(grid, 0.0) == grid
    end

    test "agrees with a brute-force dilation" do
      rng = :rand.seed_s(:exsss, 8)

      {cells, _} =
        Enum.map_reduce(1..40, rng, fn _, rng ->
          {c, rng} = :rand.uniform_s(40, rng)
          {r, rng} = :rand.uniform_s(30, rng)
          {{c - 1, r - 1}, rng}
        end)

      grid = Grid.new(40, 30, resolution: 0.05) |> Grid.put(cells, true)
      inflated = Maps.inflate(grid, 0.13)
      r2 = (0.13 / 0.05) ** 2

      expected =
        for c <- 0..39,
            r <- 0..29,
            Enum.any?(cells, fn {bc, br} -> (bc - c) ** 2 + (br - r) ** 2 <= r2 end),
            into: MapSet.new(),
            do: {c, r}

      assert blocked(inflated) == expected
    end
  end

  ## occupancy maps

  # beams towards a wall at x = 3.05 from a sensor at {0.55, 2.05} facing +x
  @sensor {0.55, 2.05, 0.0}
  defp wall_scan(range_max \\ 5.0) do
    angles = [-0.2, -0.1, 0.0, 0.1, 0.2]

    %{
      ranges: for(a <- angles, do: min(2.5 / :math.cos(a), range_max)),
      angle_min: -0.2,
      angle_increment: 0.1,
      range_max: range_max
    }
  end

  defp no_echo, do: %{wall_scan() | ranges: List.duplicate(5.0, 5)}

  describe "LogOdds" do
    test "cells along a ray become free and its end cell occupied" do
      map = LogOdds.new(50, 40, resolution: 0.1)
      once = LogOdds.update(map, wall_scan(), @sensor)
      map = Enum.reduce(1..5, map, fn _, m -> LogOdds.update(m, wall_scan(), @sensor) end)

      # the central beam: columns 5 (the sensor) to 29 on row 20, ending in column 30
      for c <- 5..29, do: assert(LogOdds.probability(map, {c, 20}) < 0.2)
      assert LogOdds.probability(map, {30, 20}) > 0.95
      assert LogOdds.probability(map, {30, 20}) > LogOdds.probability(once, {30, 20})
      assert LogOdds.probability(once, {30, 20}) > 0.5
      # beyond the wall, behind the sensor: never seen
      assert LogOdds.probability(map, {35, 20}) == 0.5
      refute LogOdds.observed?(map, {35, 20})

      grid = LogOdds.to_grid(map)
      refute Grid.passable?(grid, {30, 20})
      assert Grid.passable?(grid, {20, 20})
      assert Grid.passable?(grid, {35, 20})
      refute Grid.passable?(LogOdds.to_grid(map, 0.65, unknown: :blocked), {35, 20})
      assert Grid.passable?(LogOdds.to_grid(map, 0.65, unknown: :blocked), {20, 20})
    end

    test "clamping lets the map change its mind when the wall goes" do
      map =
        Enum.reduce(1..30, LogOdds.new(50, 40, resolution: 0.1), fn _, m ->
          LogOdds.update(m, wall_scan(), @sensor)
        end)

      assert LogOdds.log_odds(map, {30, 20}) == 3.5
      map = Enum.reduce(1..10, map, fn _, m -> LogOdds.update(m, no_echo(), @sensor) end)
      assert LogOdds.probability(map, {30, 20}) < 0.5
      # no echo: free up to range_max, nothing occupied
      assert LogOdds.probability(map, {40, 20}) < 0.5
    end
  end

  describe "FuzzyGrid" do
    test "cells along a ray become empty and its end cell occupied after repeated scans" do
      map = FuzzyGrid.new(50, 40, resolution: 0.1)
      once = FuzzyGrid.update(map, wall_scan(), @sensor)
      map = Enum.reduce(1..4, map, fn _, m -> FuzzyGrid.update(m, wall_scan(), @sensor) end)

      for c <- 6..29 do
        {e, o} = FuzzyGrid.degrees(map, {c, 20})
        assert e > 0.5 and o == 0.0
        assert FuzzyGrid.occupied(map, {c, 20}) == 0.0
      end

      {e_end, o_end} = FuzzyGrid.degrees(map, {30, 20})
      assert e_end == 0.0 and o_end > 0.8
      # one reading is not enough to call it an obstacle at 0.5
      assert FuzzyGrid.occupied(once, {30, 20}) < 0.5
      assert Grid.passable?(FuzzyGrid.to_grid(once), {30, 20})

      grid = FuzzyGrid.to_grid(map)
      refute Grid.passable?(grid, {30, 20})
      assert Grid.passable?(grid, {20, 20})
      # never seen: indeterminate, passable unless asked otherwise
      assert FuzzyGrid.indeterminate(map, {35, 20}) == 1.0
      assert Grid.passable?(grid, {35, 20})
      refute Grid.passable?(FuzzyGrid.to_grid(map, 0.5, unknown: :blocked), {35, 20})
    end

    test "seen occupied and then empty: ambiguous, not an obstacle" do
      map =
        Enum.reduce(1..4, FuzzyGrid.new(50, 40, resolution: 0.1), fn _, m ->
          FuzzyGrid.update(m, wall_scan(), @sensor)
        end)

      map = Enum.reduce(1..4, map, fn _, m -> FuzzyGrid.update(m, no_echo(), @sensor) end)
      assert FuzzyGrid.ambiguous(map, {30, 20}) > 0.5
      assert FuzzyGrid.occupied(map, {30, 20}) < 0.5
      assert Grid.passable?(FuzzyGrid.to_grid(map), {30, 20})
    end
  end

  ## segments

  defp noisy(points, rng, sd) do
    Enum.map_reduce(points, rng, fn {x, y}, rng ->
      {nx, rng} = :rand.normal_s(rng)
      {ny, rng} = :rand.normal_s(rng)
      {{x + sd * nx, y + sd * ny}, rng}
    end)
  end

  defp close?({{ax1, ay1}, {ax2, ay2}}, {{bx1, by1}, {bx2, by2}}, tol) do
    d = fn {x1, y1}, {x2, y2} -> :math.sqrt((x1 - x2) ** 2 + (y1 - y2) ** 2) end

    (d.({ax1, ay1}, {bx1, by1}) < tol and d.({ax2, ay2}, {bx2, by2}) < tol) or
      (d.({ax1, ay1}, {bx2, by2}) < tol and d.({ax2, ay2}, {bx1, by1}) < tol)
  end

  describe "Segments" do
    test "fit/2 recovers the two walls of a corner from noisy points" do
      # a scan along a wall from {0, 0} to {2, 0}, then up another to {2, 1.5}
      points = for(i <- 0..99, do: {i * 0.02, 0.0}) ++ for(i <- 0..75, do: {2.0, i * 0.02})
      {points, _} = noisy(points, :rand.seed_s(:exsss, 4), 0.01)

      assert [a, b] = Segments.fit(points, threshold: 0.05, min_points: 5)
      assert close?(a, {{0.0, 0.0}, {2.0, 0.0}}, 0.05)
      assert close?(b, {{2.0, 0.0}, {2.0, 1.5}}, 0.05)
    end

    test "fit/2 separates two parallel walls by the gap and drops stray points" do
      left = for i <- 0..40, do: {1.0, -1.0 + i * 0.05}
      right = for i <- 0..40, do: {3.0, -1.0 + i * 0.05}
      stray = [{2.0, 5.0}, {2.05, 5.0}, {2.1, 5.02}]
      {points, _} = noisy(left ++ stray ++ right, :rand.seed_s(:exsss, 2), 0.005)

      assert [a, b] = Segments.fit(points)
      assert close?(a, {{1.0, -1.0}, {1.0, 1.0}}, 0.03)
      assert close?(b, {{3.0, -1.0}, {3.0, 1.0}}, 0.03)
      # with min_points 3 the stray points make a segment of their own
      assert length(Segments.fit(points, min_points: 3)) == 3
    end

    test "from_wdf/2: walls, obstacle edges and closed doors" do
      wdf = ThinkingCap.Config.read!(@office)
      segments = Segments.from_wdf(wdf)
      assert length(segments) == length(wdf.walls) + 1
      assert {{15.5, 3.0}, {16.5, 3.0}} in segments
      assert Segments.from_wdf(wdf, closed: []) == wdf.walls

      square = %{name: :s, polygon: [{0, 0}, {1, 0}, {1, 1}, {0, 1}]}
      assert length(Segments.from_wdf(%WDF{name: "s", obstacles: [square]})) == 4
      assert Segments.from_wdf(%WDF{name: "s", obstacles: [square]}, obstacles: false) == []
    end
  end
end
