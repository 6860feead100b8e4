defmodule ThinkingCap.Sim.RaycastTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Sim.Raycast

  @maps Path.expand("../../../../../priv/maps", __DIR__)
  @eps 1.0e-9

  defp world!(opts) do
    {:ok, world} = Raycast.new(opts)
    world
  end

  defp cast1(world, ray, opts \\ []) do
    [result] = Raycast.cast_rays(world, [ray], opts)
    result
  end

  defp readings(bin), do: for(<<r::float-little-64 <- bin>>, do: r)

  defp scan1(world, pose, groups, exclude \\ -1, seed \\ 0) do
    [r] = readings(Raycast.scan(world, pose, groups, exclude, seed))
    r
  end

  ## reference geometry (brute force, independent of the NIF's traversal)

  # entry distance of the ray into the union of convex polygons, or nil
  defp ray_polygons({x, y, a, _max}, polygons) do
    {dx, dy} = {:math.cos(a), :math.sin(a)}

    polygons
    |> Enum.flat_map(fn poly -> Enum.zip(poly, tl(poly) ++ [hd(poly)]) end)
    |> Enum.flat_map(fn {{ax, ay}, {bx, by}} ->
      {ex, ey} = {bx - ax, by - ay}
      den = dx * ey - dy * ex
      {wx, wy} = {ax - x, ay - y}

      if abs(den) < 1.0e-15 do
        []
      else
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
        if t >= 0 and u >= 0 and u <= 1, do: [t], else: []
      end
    end)
    |> Enum.min(fn -> nil end)
  end

  # entry distance of the ray (unit direction) into a disc: 0 from inside,
  # nil when it misses
  defp ray_circle({x, y, dx, dy}, {cx, cy, r}) do
    {mx, my} = {x - cx, y - cy}
    b = mx * dx + my * dy
    c = mx * mx + my * my - r * r
    disc = b * b - c

    cond do
      c <= 0 -> 0.0
      b > 0 or disc < 0 -> nil
      true -> -b - :math.sqrt(disc)
    end
  end

  defp point_polygons({x, y}, polygons) do
    polygons
    |> Enum.flat_map(fn poly -> Enum.zip(poly, tl(poly) ++ [hd(poly)]) end)
    |> Enum.map(fn {{ax, ay}, {bx, by}} ->
      {ex, ey} = {bx - ax, by - ay}
      u = (((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey)) |> max(0.0) |> min(1.0)
      :math.sqrt(:math.pow(x - ax - u * ex, 2) + :math.pow(y - ay - u * ey, 2))
    end)
    |> Enum.min()
  end

  # world-frame squares of the obstacle cells (value >= 50)
  defp obstacle_polygons(%{width: w, height: h, resolution: res, origin: {ox, oy, yaw}} = grid) do
    {c, s} = {:math.cos(yaw), :math.sin(yaw)}
    corner = fn i, j -> {ox + c * i * res - s * j * res, oy + s * i * res + c * j * res} end

    for row <- 0..(h - 1), col <- 0..(w - 1), cell(grid, col, row) >= 50 do
      [
        corner.(col, row),
        corner.(col + 1, row),
        corner.(col + 1, row + 1),
        corner.(col, row + 1)
      ]
    end
  end

  defp cell(%{width: w, data: data}, col, row) do
    <<_::binary-size(row * w + col), v::signed-8, _::binary>> = data
    v
  end

  # the cell value under a world point, nil outside the grid
  defp cell_at(%{width: w, height: h, resolution: res, origin: {ox, oy, yaw}} = grid, {x, y}) do
    {c, s} = {:math.cos(yaw), :math.sin(yaw)}
    gx = (c * (x - ox) + s * (y - oy)) / res
    gy = (-s * (x - ox) + c * (y - oy)) / res
    {col, row} = {floor(gx), floor(gy)}
    if col in 0..(w - 1) and row in 0..(h - 1), do: cell(grid, col, row), else: nil
  end

  defp random_grid(w, h, res, origin, density) do
    data =
      for _ <- 1..(w * h), into: <<>> do
        v =
          if :rand.uniform() < density,
            do: Enum.random([50, 77, 100]),
            else: Enum.random([-1, 0, 10, 49])

        <<v::signed-8>>
      end

    %{width: w, height: h, resolution: res, origin: origin, data: data}
  end

  defp grid_data(w, h, occupied?) do
    for row <- 0..(h - 1), col <- 0..(w - 1), into: <<>> do
      <<if(occupied?.(col, row), do: 100, else: 0)::signed-8>>
    end
  end

  # compares cast_rays with the brute-force entry distance for random rays
  # from free points in the box
  defp check_grid_rays(grid, {x0, x1, y0, y1}, n, max_range) do
    world = world!(grid: grid)
    polygons = obstacle_polygons(grid)

    rays =
      Stream.repeatedly(fn ->
        {x0 + :rand.uniform() * (x1 - x0), y0 + :rand.uniform() * (y1 - y0),
         :rand.uniform() * 2 * :math.pi(), max_range}
      end)
      |> Stream.reject(fn {x, y, _, _} -> (cell_at(grid, {x, y}) || 0) >= 50 end)
      |> Enum.take(n)

    results = Raycast.cast_rays(world, rays)

    hits =
      for {ray, result} <- Enum.zip(rays, results), reduce: 0 do
        hits ->
          case ray_polygons(ray, polygons) do
            t when is_float(t) and t <= max_range ->
              assert %{hit: :grid, id: -1, bounces: 0} = result
              assert_in_delta result.range, t, @eps, "ray #{inspect(ray)}"
              hits + 1

            _ ->
              assert result == %{hit: :none, range: max_range / 1, bounces: 0, id: -1}
              hits
          end
      end

    # the comparison is meaningful: most rays hit something, not all
    assert hits > n / 10
    assert hits < n
  end

  describe "segments" do
    setup do
      # a wall at x = 2 and one behind it at x = 4
      %{world: world!(segments: [{{2, -5}, {2, 5}}, {{4.0, -5.0}, {4.0, 5.0}}])}
    end

    test "a perpendicular ray hits the wall at its distance", %{world: w} do
      assert %{hit: :segment, id: 0, range: r, bounces: 0} = cast1(w, {0, 0, 0, 10})
      assert_in_delta r, 2.0, @eps
      assert_in_delta cast1(w, {2.5, 1, :math.pi(), 10}).range, 0.5, @eps
    end

    test "an oblique ray reads d / cos(phi)", %{world: w} do
      for phi <- [0.3, -0.7, 1.1] do
        assert %{hit: :segment, id: 0, range: r} = cast1(w, {0, 0, phi, 20})
        assert_in_delta r, 2 / :math.cos(phi), @eps
      end
    end

    test "a ray that misses, or is too short, reads its max range", %{world: w} do
      assert cast1(w, {0, 0, :math.pi(), 10}) == %{range: 10.0, hit: :none, bounces: 0, id: -1}
      assert cast1(w, {0, 0, 0, 1.5}) == %{range: 1.5, hit: :none, bounces: 0, id: -1}
      # passes beyond the end of the wall
      assert %{hit: :none} = cast1(w, {0, 0, 1.5, 7})
    end

    test "a disabled segment is not hit, a re-enabled one is", %{world: w} do
      assert :ok = Raycast.set_segment(w, 0, false)
      assert %{hit: :segment, id: 1, range: r} = cast1(w, {0, 0, 0, 10})
      assert_in_delta r, 4.0, @eps
      assert :ok = Raycast.set_segment(w, 1, false)
      assert %{hit: :none} = cast1(w, {0, 0, 0, 10})
      assert :ok = Raycast.set_segment(w, 0, true)
      assert %{hit: :segment, id: 0} = cast1(w, {0, 0, 0, 10})
    end

    test "unknown segment ids are refused", %{world: w} do
      assert_raise ArgumentError, fn -> Raycast.set_segment(w, 2, true) end
      assert_raise ArgumentError, fn -> Raycast.set_segment(w, -1, true) end
    end

    test "many segments (bucket index) agree with brute force" do
      :rand.seed(:exsss, {7, 8, 9})

      segments =
        for _ <- 1..300 do
          {x, y} = {:rand.uniform() * 40 - 20, :rand.uniform() * 40 - 20}
          a = :rand.uniform() * :math.pi()
          l = 0.2 + :rand.uniform() * 3
          {{x, y}, {x + l * :math.cos(a), y + l * :math.sin(a)}}
        end

      w = world!(segments: segments)
      polygons = for {p, q} <- segments, do: [p, q]

      rays =
        for _ <- 1..300,
            do: {:rand.uniform() * 50 - 25, :rand.uniform() * 50 - 25, :rand.uniform() * 7, 30.0}

      for {ray, result} <- Enum.zip(rays, Raycast.cast_rays(w, rays)) do
        case ray_polygons(ray, polygons) do
          nil ->
            assert result.hit == :none

          t ->
            assert result.hit == :segment
            assert_in_delta result.range, t, @eps
        end
      end
    end
  end

  describe "occupancy grid" do
    test "the hit is the entry point of the first obstacle cell" do
      # a column of obstacle cells at col 5: x in [0.5, 0.6)
      data = grid_data(10, 10, fn col, _row -> col == 5 end)
      w = world!(grid: %{width: 10, height: 10, resolution: 0.1, origin: {0, 0, 0}, data: data})

      assert %{hit: :grid, id: -1, range: r} = cast1(w, {0.05, 0.05, 0, 10})
      assert_in_delta r, 0.45, @eps
      assert_in_delta cast1(w, {0.05, 0.05, 0.3, 10}).range, 0.45 / :math.cos(0.3), @eps
      # from the right side, the entry is the cell's right face x = 0.6
      assert_in_delta cast1(w, {0.95, 0.55, :math.pi(), 10}).range, 0.35, @eps
      # from outside the grid
      assert_in_delta cast1(w, {-1.0, 0.55, 0, 10}).range, 1.5, @eps
      # beyond the grid everything is free
      assert %{hit: :none, range: 3.0} = cast1(w, {0.05, 0.05, :math.pi(), 3})
    end

    test "values >= 50 are obstacles, unknown and lower values are free" do
      data = <<-1, 49, 50, 0, 100>>
      w = world!(grid: %{width: 5, height: 1, resolution: 1.0, origin: {0, 0, 0}, data: data})
      assert_in_delta cast1(w, {0.5, 0.5, 0, 10}).range, 1.5, @eps
      assert_in_delta cast1(w, {3.5, 0.5, 0, 10}).range, 0.5, @eps
    end

    test "random rays in a random grid match the analytic entry distance" do
      :rand.seed(:exsss, {1, 2, 3})
      grid = random_grid(20, 15, 0.05, {-0.3, 0.2, 0.0}, 0.08)
      check_grid_rays(grid, {-0.5, 0.9, 0.0, 1.1}, 300, 3.0)
    end

    test "long rays across sparse free space (distance-field skipping) stay exact" do
      :rand.seed(:exsss, {4, 5, 6})
      grid = random_grid(200, 160, 0.05, {1.0, -2.0, 0.0}, 0.004)
      check_grid_rays(grid, {1.0, 11.0, -2.0, 6.0}, 200, 15.0)
    end

    # A trace tests the bodies first and marches the grid only up to the
    # nearest one: bodies in front of walls, behind them and inside
    # obstacle cells must all give the nearer of the two.
    test "bodies among obstacle cells: the nearer of wall and body, as brute force" do
      :rand.seed(:exsss, {8, 6, 4})
      grid = random_grid(120, 90, 0.05, {-1.0, -1.5, 0.4}, 0.01)
      polygons = obstacle_polygons(grid)

      bodies =
        for _ <- 1..40,
            do:
              {-2.0 + :rand.uniform() * 6.0, -1.0 + :rand.uniform() * 6.0,
               0.05 + 0.2 * :rand.uniform()}

      world = world!(grid: grid)
      :ok = Raycast.set_bodies(world, bodies)

      # from free cells (inside an obstacle cell a ray reads 0)
      rays =
        for _ <- 1..400,
            ray =
              {-2.0 + :rand.uniform() * 6.0, -1.0 + :rand.uniform() * 6.0,
               :rand.uniform() * 2 * :math.pi(), 4.0},
            (cell_at(grid, {elem(ray, 0), elem(ray, 1)}) || 0) < 50,
            do: ray

      kinds =
        for {{x, y, a, max} = ray, got} <- Enum.zip(rays, Raycast.cast_rays(world, rays)) do
          wall = ray_polygons(ray, polygons)
          {dx, dy} = {:math.cos(a), :math.sin(a)}
          body = bodies |> Enum.map(&ray_circle({x, y, dx, dy}, &1)) |> Enum.min(fn -> nil end)

          case Enum.reject([{wall, :grid}, {body, :body}], &(elem(&1, 0) == nil)) do
            [] ->
              assert got.hit == :none and got.range == max
              :none

            candidates ->
              {t, kind} = Enum.min_by(candidates, &elem(&1, 0))

              if t > max do
                assert got.hit == :none
                :none
              else
                assert got.hit == kind,
                       "ray #{inspect(ray)}: #{inspect(got)}, expected #{kind} at #{t}"

                assert_in_delta got.range, t, 1.0e-7
                kind
              end
          end
        end

      # both kinds of hit occur, and misses
      assert Enum.count(kinds, &(&1 == :body)) > 20
      assert Enum.count(kinds, &(&1 == :grid)) > 20
      assert :none in kinds
    end

    test "a rotated random grid matches the analytic entry distance" do
      :rand.seed(:exsss, {3, 2, 1})
      grid = random_grid(40, 30, 0.1, {0.5, -0.25, -2.0}, 0.03)
      check_grid_rays(grid, {-3.0, 1.5, -4.0, 0.0}, 300, 6.0)
    end

    test "testmap.yaml (origin yaw 1 rad) matches the analytic entry distance" do
      {:ok, map} = RosMap.load(Path.join(@maps, "testmap.yaml"))
      assert {_, _, 1.0} = map.origin
      :rand.seed(:exsss, {2, 2, 2})
      check_grid_rays(map, {0.8, 3.0, 2.7, 4.7}, 300, 3.0)
    end

    test "the warehouse map loads and rays from a free cell hit its walls" do
      {:ok, map} = RosMap.load(Path.join(@maps, "warehouse.yaml"))
      w = world!(grid: map)
      {ox, oy, _} = map.origin
      # from the centre of the map towards the outer walls
      {cx, cy} = {ox + map.width * map.resolution / 2, oy + map.height * map.resolution / 2}

      results = Raycast.cast_rays(w, for(k <- 0..7, do: {cx, cy, k * :math.pi() / 4, 100.0}))

      for r <- results do
        assert r.hit == :grid
        assert r.range < 30
      end
    end
  end

  describe "bodies" do
    test "a circle reads d - r, an excluded body is not seen" do
      w = world!([])
      :ok = Raycast.set_bodies(w, [{3, 0, 0.5}, {0, 5, 1}])
      assert %{hit: :body, id: 0, range: r} = cast1(w, {0, 0, 0, 10})
      assert_in_delta r, 2.5, @eps
      assert %{hit: :body, id: 1, range: r1} = cast1(w, {0, 0, :math.pi() / 2, 10})
      assert_in_delta r1, 4.0, @eps
      # off-centre: the chord's near end
      assert_in_delta cast1(w, {0, 0.3, 0, 10}).range, 3 - :math.sqrt(0.25 - 0.09), @eps
      assert %{hit: :none} = cast1(w, {0, 0, 0, 10}, exclude: 0)
      assert %{hit: :body, id: 0} = cast1(w, {0, 0, 0, 10}, exclude: 1)
    end

    test "set_bodies replaces the previous set" do
      w = world!(segments: [{{10, -1}, {10, 1}}])
      :ok = Raycast.set_bodies(w, [{3, 0, 0.5}])
      assert %{hit: :body} = cast1(w, {0, 0, 0, 20})
      :ok = Raycast.set_bodies(w, [{0, 3, 0.5}])
      assert %{hit: :segment, id: 0} = cast1(w, {0, 0, 0, 20})
      assert %{hit: :body, id: 0} = cast1(w, {0, 0, :math.pi() / 2, 20})
      :ok = Raycast.set_bodies(w, [])
      assert %{hit: :none} = cast1(w, {0, 0, :math.pi() / 2, 20})
    end

    test "a body nearer than a wall or grid cell wins" do
      data = grid_data(10, 10, fn col, _ -> col == 9 end)
      w = world!(grid: %{width: 10, height: 10, resolution: 1, origin: {0, 0, 0}, data: data})
      assert_in_delta cast1(w, {0.5, 5.5, 0, 20}).range, 8.5, @eps
      :ok = Raycast.set_bodies(w, [{5.0, 5.5, 1.0}])
      assert %{hit: :body, range: r} = cast1(w, {0.5, 5.5, 0, 20})
      assert_in_delta r, 3.5, @eps
    end

    test "bad bodies are refused" do
      w = world!([])
      assert_raise ArgumentError, fn -> Raycast.set_bodies(w, [{0, 0, -1}]) end
      assert_raise ArgumentError, fn -> Raycast.set_bodies(w, [{0, :a, 1}]) end
      assert_raise ArgumentError, fn -> Raycast.set_bodies(w, :nope) end
    end

    test "set_bodies_packed: records in any order, ids no record names parked far away" do
      w = world!([])
      bodies = [{3, 0, 0.5}, {0, 5, 1}, {-4, 0, 0.3}, {0, -2, 0.2}]

      rays =
        for k <- 0..35, x0 <- [0.0, 1.0, -1.5] do
          {x0, 0.25, k * :math.pi() / 18, 10}
        end

      :ok = Raycast.set_bodies(w, bodies ++ [{1.0e9, 1.0e9, 0.0}])
      expected = Raycast.cast_rays(w, rays, exclude: 2)
      clear = Raycast.clearance(w, 1.0, 1.0, -1, 10)

      records =
        bodies
        |> Enum.with_index(fn {x, y, r}, i -> Raycast.body_record(i, x, y, r) end)
        |> Enum.reverse()
        |> IO.iodata_to_binary()

      :ok = Raycast.set_bodies(w, [])
      :ok = Raycast.set_bodies_packed(w, 5, records)
      assert Raycast.cast_rays(w, rays, exclude: 2) == expected
      assert Raycast.clearance(w, 1.0, 1.0, -1, 10) == clear
      assert Enum.any?(expected, &(&1.hit == :body))

      # a later record of the same id wins
      :ok =
        Raycast.set_bodies_packed(
          w,
          1,
          Raycast.body_record(0, 3, 0, 0.5) <> Raycast.body_record(0, 6, 0, 0.5)
        )

      assert_in_delta cast1(w, {0, 0, 0, 10}).range, 5.5, @eps
    end

    test "set_bodies_packed refuses bad records" do
      w = world!([])

      assert_raise ArgumentError, fn ->
        Raycast.set_bodies_packed(w, 1, Raycast.body_record(1, 0, 0, 1))
      end

      assert_raise ArgumentError, fn ->
        Raycast.set_bodies_packed(w, 1, Raycast.body_record(0, 0, 0, -1))
      end

      assert_raise ArgumentError, fn -> Raycast.set_bodies_packed(w, 1, <<1, 2, 3>>) end
      assert_raise ArgumentError, fn -> Raycast.set_bodies_packed(w, -1, <<>>) end
      nan = <<0, 0, 0, 0, 0, 0, 248, 127>>
      bad = <<0.0::float-native-64, nan::binary, 0.0::float-native-64, 1.0::float-native-64>>
      assert_raise ArgumentError, fn -> Raycast.set_bodies_packed(w, 1, bad) end
    end

    test "contacts refuses bad moves" do
      assert Raycast.contacts(<<>>) == []
      assert_raise ArgumentError, fn -> Raycast.contacts(<<1, 2, 3>>) end

      assert_raise ArgumentError, fn ->
        Raycast.contacts(Raycast.move_record(0, 0, 0, 1, 1, -0.2))
      end

      # an id that is not a whole number
      rest = Raycast.move_record(0, 0, 0, 1, 1, 0.2) |> binary_part(8, 40)
      assert_raise ArgumentError, fn -> Raycast.contacts(<<1.5::float-native-64>> <> rest) end
    end
  end

  describe "reflections" do
    # wall A along y = 1; a ray from the origin at angle theta meets it after
    # 1/sin(theta) with incidence pi/2 - theta
    @theta 0.2
    @d2 1.0

    defp hit_a, do: {1 / :math.tan(@theta), 1.0}

    # wall B across the reflected ray, @d2 after the hit on A: hit head-on
    defp wall_b do
      {hx, hy} = hit_a()
      {qx, qy} = {hx + @d2 * :math.cos(@theta), hy - @d2 * :math.sin(@theta)}
      {px, py} = {0.15 * :math.sin(@theta), 0.15 * :math.cos(@theta)}
      {{qx - px, qy - py}, {qx + px, qy + py}}
    end

    test "a shallow hit reflects: no echo without bounces" do
      w = world!(segments: [{{-10, 1}, {10, 1}}])
      opts = [max_bounces: 0, critical_angle: 0.26]
      assert %{hit: :none, range: 10.0, id: -1} = cast1(w, {0, 0, @theta, 10}, opts)
      # with the default critical angle every hit echoes
      assert_in_delta cast1(w, {0, 0, @theta, 10}).range, 1 / :math.sin(@theta), @eps
    end

    test "a near-perpendicular hit gives the direct distance" do
      w = world!(segments: [{{-10, 1}, {10, 1}}])
      a = :math.pi() / 2 - 0.1
      r = cast1(w, {0, 0, a, 10}, max_bounces: 2, critical_angle: 0.26)
      assert %{hit: :segment, id: 0, bounces: 0} = r
      assert_in_delta r.range, 1 / :math.sin(a), @eps
    end

    test "the bounced ray hitting a second wall head-on reads the total path" do
      w = world!(segments: [{{-10, 1}, {10, 1}}, wall_b()])
      opts = [max_bounces: 1, critical_angle: 0.26]
      r = cast1(w, {0, 0, @theta, 10}, opts)
      assert %{hit: :segment, id: 1, bounces: 1} = r
      assert_in_delta r.range, 1 / :math.sin(@theta) + @d2, 1.0e-8
      # not enough range for the second leg
      assert %{hit: :none, range: 6.0} = cast1(w, {0, 0, @theta, 6.0}, opts)
      # no bounce allowed
      assert %{hit: :none} = cast1(w, {0, 0, @theta, 10}, max_bounces: 0, critical_angle: 0.26)
    end

    test "grid walls reflect with the neighbourhood normal" do
      # floor: rows 0..19 (top face y = 1.0); wall: cols >= 150 (x >= 7.5)
      data = grid_data(200, 100, fn col, row -> row < 20 or col >= 150 end)
      grid = %{width: 200, height: 100, resolution: 0.05, origin: {0, 0, 0}, data: data}
      w = world!(grid: grid)
      opts = [max_bounces: 1, critical_angle: 0.26]
      r = cast1(w, {1.0, 2.0, -@theta, 20}, opts)
      t1 = 1 / :math.sin(@theta)
      t2 = (7.5 - 1.0 - t1 * :math.cos(@theta)) / :math.cos(@theta)
      assert %{hit: :grid, bounces: 1} = r
      assert_in_delta r.range, t1 + t2, 1.0e-7

      assert %{hit: :none, range: 20.0} =
               cast1(w, {1.0, 2.0, -@theta, 20}, max_bounces: 0, critical_angle: 0.26)

      # head-on to the wall: the direct distance
      assert_in_delta cast1(w, {1.0, 2.0, 0.0, 20}, opts).range, 6.5, @eps
    end

    test "the same in a rotated grid" do
      yaw = 0.7
      data = grid_data(200, 100, fn col, row -> row < 20 or col >= 150 end)
      grid = %{width: 200, height: 100, resolution: 0.05, origin: {3.0, -1.0, yaw}, data: data}
      w = world!(grid: grid)
      # the ray of the previous test, in world coordinates
      {x, y} =
        {3.0 + 1.0 * :math.cos(yaw) - 2.0 * :math.sin(yaw),
         -1.0 + 1.0 * :math.sin(yaw) + 2.0 * :math.cos(yaw)}

      r = cast1(w, {x, y, yaw - @theta, 20}, max_bounces: 1, critical_angle: 0.26)
      t1 = 1 / :math.sin(@theta)
      t2 = (7.5 - 1.0 - t1 * :math.cos(@theta)) / :math.cos(@theta)
      assert %{hit: :grid, bounces: 1} = r
      assert_in_delta r.range, t1 + t2, 1.0e-7
    end

    test "grid walls at the grid's edges reflect as the same walls inside a larger grid" do
      # walls 1 cell from the edges (a hit's 5 x 5 neighbourhood leaves the
      # grid), then the same cells with 10 free cells all round
      occupied? = fn col, row -> col >= 58 or row < 3 or (col < 2 and row > 30) end
      edge = grid_data(60, 40, occupied?)

      padded =
        grid_data(80, 60, fn col, row ->
          col in 10..69 and row in 10..49 and occupied?.(col - 10, row - 10)
        end)

      res = 0.05

      w_edge =
        world!(grid: %{width: 60, height: 40, resolution: res, origin: {0, 0, 0}, data: edge})

      w_padded =
        world!(
          grid: %{width: 80, height: 60, resolution: res, origin: {-0.5, -0.5, 0}, data: padded}
        )

      opts = [max_bounces: 2, critical_angle: 0.26]

      rays =
        for k <- 0..60 do
          {0.6 + 0.02 * k, 1.0, -3.1 + k * 0.103, 6.0}
        end

      for ray <- rays do
        a = cast1(w_edge, ray, opts)
        b = cast1(w_padded, ray, opts)
        assert {a.hit, a.bounces} == {b.hit, b.bounces}, "ray #{inspect(ray)}"
        assert_in_delta a.range, b.range, @eps
      end

      assert Enum.count(rays, &(cast1(w_edge, &1, opts).bounces > 0)) > 10
    end

    test "bodies reflect off-centre hits and echo head-on ones" do
      w = world!([])
      :ok = Raycast.set_bodies(w, [{3, 0, 1}])
      opts = [max_bounces: 0, critical_angle: 0.26]
      assert %{hit: :none} = cast1(w, {0, 0.9, 0, 10}, opts)
      assert %{hit: :body, range: r} = cast1(w, {0, 0, 0, 10}, opts)
      assert_in_delta r, 2.0, @eps
    end
  end

  describe "scan/5" do
    setup do
      %{world: world!(segments: [{{2, -5}, {2, 5}}])}
    end

    defp sonar(extra), do: Map.merge(%{max_range: 5.0, min_range: 0.1}, extra)

    test "a group reads the minimum over its rays", %{world: w} do
      # rays at 0.1, 0.3 and 0.5 rad
      g = Raycast.pack_groups([sonar(%{heading: 0.3, fov: 0.6, rays: 3})])
      assert_in_delta scan1(w, {0, 0, 0}, g), 2 / :math.cos(0.1), @eps
      # nothing in sight: max range
      assert scan1(w, {0, 0, :math.pi()}, g) == 5.0
    end

    test "sensor poses are in the robot frame", %{world: w} do
      g = Raycast.pack_groups([sonar(%{x: 0.5, heading: -:math.pi() / 2})])
      assert_in_delta scan1(w, {1, 1, :math.pi() / 2}, g), 1.0, @eps
      # and the robot's own body is excluded
      :ok = Raycast.set_bodies(w, [{1, 1, 0.7}])
      assert_in_delta scan1(w, {1, 1, :math.pi() / 2}, g, -1), 0.1, @eps
      assert_in_delta scan1(w, {1, 1, :math.pi() / 2}, g, 0), 1.0, @eps
    end

    test "one reading per group, in order", %{world: w} do
      g = Raycast.pack_groups([sonar(%{}), sonar(%{heading: :math.pi()}), sonar(%{heading: 0.5})])
      assert [r0, 5.0, r2] = readings(Raycast.scan(w, {0, 0, 0}, g, -1, 0))
      assert_in_delta r0, 2.0, @eps
      assert_in_delta r2, 2 / :math.cos(0.5), @eps
    end

    test "scan_list/5 gives the same readings as a list", %{world: w} do
      g =
        Raycast.pack_groups(
          for h <- [0.0, 0.4, 3.0], do: sonar(%{heading: h, noise_std: 0.05, dropout: 0.3})
        )

      for seed <- 1..20 do
        assert Raycast.scan_list(w, {0, 0, 0.1}, g, -1, seed) ==
                 readings(Raycast.scan(w, {0, 0, 0.1}, g, -1, seed))
      end
    end

    test "deterministic: same seed same bytes, different seeds differ", %{world: w} do
      g =
        Raycast.pack_groups([sonar(%{noise_std: 0.05}), sonar(%{heading: 0.2, noise_std: 0.05})])

      a = Raycast.scan(w, {0, 0, 0}, g, -1, 42)
      assert byte_size(a) == 16
      assert a == Raycast.scan(w, {0, 0, 0}, g, -1, 42)
      refute a == Raycast.scan(w, {0, 0, 0}, g, -1, 43)
      # without noise the seed does not matter
      g0 = Raycast.pack_groups([sonar(%{})])
      assert Raycast.scan(w, {0, 0, 0}, g0, -1, 1) == Raycast.scan(w, {0, 0, 0}, g0, -1, 2)
    end

    test "Gaussian noise: mean (with bias) and standard deviation", %{world: w} do
      g = Raycast.pack_groups([sonar(%{noise_std: 0.05, noise_prop: 0.01, bias: 0.1})])
      n = 4000
      rs = for seed <- 1..n, do: scan1(w, {0, 0, 0}, g, -1, seed)
      mean = Enum.sum(rs) / n
      std = :math.sqrt(Enum.sum(for r <- rs, do: (r - mean) * (r - mean)) / (n - 1))
      # sigma = 0.05 + 0.01 * 2.0; standard error of the mean 0.0011
      assert_in_delta mean, 2.1, 0.006
      assert_in_delta std, 0.07, 0.07 * 0.08
    end

    # the noise's shape, not only its first two moments: the share within
    # 1, 2 and 3 standard deviations, the fourth moment, and draws from
    # the tail beyond the ziggurat's base (3.44 sigma)
    test "Gaussian noise: its shape and its tails" do
      # a wall 20 m away: no reading near the range's ends, so none clamped
      w = world!(segments: [{{20, -50}, {20, 50}}])
      groups = for k <- 0..49, do: sonar(%{heading: k * 0.01, noise_std: 1.0, max_range: 100.0})
      g = Raycast.pack_groups(groups)

      clean =
        readings(
          Raycast.scan(
            w,
            {0, 0, 0},
            Raycast.pack_groups(Enum.map(groups, &Map.put(&1, :noise_std, 0.0))),
            -1,
            0
          )
        )

      zs =
        for seed <- 1..600,
            {r, r0} <- Enum.zip(readings(Raycast.scan(w, {0, 0, 0}, g, -1, seed)), clean),
            do: r - r0

      n = length(zs)
      share = fn k -> Enum.count(zs, &(abs(&1) < k)) / n end
      mean = Enum.sum(zs) / n
      var = Enum.sum(for z <- zs, do: (z - mean) * (z - mean)) / n
      kurtosis = Enum.sum(for z <- zs, do: :math.pow(z - mean, 4)) / n / (var * var)

      assert n == 30_000
      assert_in_delta mean, 0.0, 0.025
      assert_in_delta :math.sqrt(var), 1.0, 0.02
      assert_in_delta share.(1), 0.6827, 0.01
      assert_in_delta share.(2), 0.9545, 0.005
      assert_in_delta share.(3), 0.9973, 0.0012
      assert_in_delta kurtosis, 3.0, 0.15
      # expected about 17 beyond the base on both sides
      beyond = Enum.count(zs, &(abs(&1) > 3.4426))
      assert beyond in 5..40
      assert Enum.any?(zs, &(&1 > 3.4426)) and Enum.any?(zs, &(&1 < -3.4426))
      # and the tail itself is drawn, not only its start (about 10 expected)
      assert Enum.count(zs, &(abs(&1) > 3.6)) >= 2
    end

    test "noise is clamped to the range, echo-less readings get none", %{world: w} do
      g = Raycast.pack_groups([sonar(%{min_range: 1.9, max_range: 2.1, noise_std: 1.0})])
      rs = for seed <- 1..500, do: scan1(w, {0, 0, 0}, g, -1, seed)
      assert Enum.all?(rs, &(&1 >= 1.9 and &1 <= 2.1))
      assert Enum.count(rs, &(&1 == 1.9)) > 100
      assert Enum.count(rs, &(&1 == 2.1)) > 100

      g = Raycast.pack_groups([sonar(%{noise_std: 1.0, dropout: 0.5})])
      assert Enum.all?(1..200, fn seed -> scan1(w, {0, 0, :math.pi()}, g, -1, seed) == 5.0 end)
    end

    test "dropout and spike frequencies", %{world: w} do
      g = Raycast.pack_groups([sonar(%{dropout: 0.2, spike: 0.3})])
      n = 4000
      rs = for seed <- 1..n, do: scan1(w, {0, 0, 0}, g, -1, seed)
      dropped = Enum.count(rs, &(&1 == 5.0))
      spiked = Enum.count(rs, &(&1 != 5.0 and abs(&1 - 2.0) > 1.0e-12))
      # 4 standard deviations of a binomial count
      assert_in_delta dropped, 0.2 * n, 4 * :math.sqrt(n * 0.2 * 0.8)
      assert_in_delta spiked, 0.3 * n, 4 * :math.sqrt(n * 0.3 * 0.7)
      spikes = Enum.filter(rs, &(&1 != 5.0 and abs(&1 - 2.0) > 1.0e-12))
      assert Enum.all?(spikes, &(&1 >= 0.1 and &1 <= 5.0))
      # uniform over [0.1, 5.0]
      assert_in_delta Enum.sum(spikes) / length(spikes), 2.55, 0.15

      # exclusive faults: beyond a total of 1, spikes get 1 - dropout
      g = Raycast.pack_groups([sonar(%{dropout: 0.7, spike: 0.7})])
      rs = for seed <- 1..2000, do: scan1(w, {0, 0, 0}, g, -1, seed)
      assert_in_delta Enum.count(rs, &(&1 == 5.0)), 1400, 4 * :math.sqrt(2000 * 0.21)

      assert_in_delta Enum.count(rs, &(abs(&1 - 2.0) > 1.0e-12 and &1 != 5.0)),
                      600,
                      4 * :math.sqrt(2000 * 0.21)
    end

    test "spikes with a magnitude stay within it; echo-less readings may spike", %{world: w} do
      g = Raycast.pack_groups([sonar(%{spike: 0.5, spike_magnitude: 0.4})])
      rs = for seed <- 1..1000, do: scan1(w, {0, 0, 0}, g, -1, seed)
      assert Enum.all?(rs, &(&1 >= 1.6 and &1 <= 2.4))
      assert_in_delta Enum.count(rs, &(abs(&1 - 2.0) > 1.0e-12)), 500, 4 * :math.sqrt(250)

      g = Raycast.pack_groups([sonar(%{spike: 0.5})])
      rs = for seed <- 1..1000, do: scan1(w, {0, 0, :math.pi()}, g, -1, seed)
      assert_in_delta Enum.count(rs, &(&1 < 5.0)), 500, 4 * :math.sqrt(250)
    end

    test "crosstalk: a bounced echo reaches the other transducer whose cone contains it" do
      w = world!(segments: [{{-10, 1}, {10, 1}}, wall_b()])
      # sonar 0 at the origin: A, then B head-on; P = the hit on B
      {hx, hy} = hit_a()
      p = {hx + @d2 * :math.cos(@theta), hy - @d2 * :math.sin(@theta)}
      path = 1 / :math.sin(@theta) + @d2
      # sonar 1 below P, looking up-left: its own ray grazes A and is lost,
      # but P lies in its cone (0.3 rad off its axis, fov 1.0)
      s1 = {elem(p, 0), -1.0}
      base = %{max_range: 10.0, max_bounces: 1, critical_angle: 0.26, ring: 0}
      g0 = Map.merge(base, %{heading: @theta})

      g1 =
        Map.merge(base, %{
          x: elem(s1, 0),
          y: elem(s1, 1),
          heading: :math.pi() / 2 + 0.3,
          fov: 1.0,
          max_bounces: 0
        })

      [r0, r1] = readings(Raycast.scan(w, {0, 0, 0}, Raycast.pack_groups([g0, g1]), -1, 0))
      assert_in_delta r0, path, 1.0e-8
      expected = (path + (elem(p, 1) - elem(s1, 1))) / 2
      assert_in_delta r1, expected, 1.0e-8

      # without a ring, or in different rings: no crosstalk
      [_, lone] =
        readings(
          Raycast.scan(
            w,
            {0, 0, 0},
            Raycast.pack_groups([%{g0 | ring: -1}, %{g1 | ring: -1}]),
            -1,
            0
          )
        )

      assert lone == 10.0

      [_, other_ring] =
        readings(Raycast.scan(w, {0, 0, 0}, Raycast.pack_groups([g0, %{g1 | ring: 1}]), -1, 0))

      assert other_ring == 10.0

      # P outside the cone
      [_, narrow] =
        readings(Raycast.scan(w, {0, 0, 0}, Raycast.pack_groups([g0, %{g1 | fov: 0.4}]), -1, 0))

      assert narrow == 10.0
    end

    test "group readings agree with cast_rays among many bodies (bodies culled by direction)" do
      :rand.seed(:exsss, {5, 5, 5})

      w =
        world!(
          segments: [
            {{-9, -9}, {9, -9}},
            {{9, -9}, {9, 9}},
            {{9, 9}, {-9, 9}},
            {{-9, 9}, {-9, -9}}
          ]
        )

      bodies =
        for _ <- 1..40,
            do: {:rand.uniform() * 16 - 8, :rand.uniform() * 16 - 8, 0.05 + :rand.uniform() * 0.4}

      :ok = Raycast.set_bodies(w, bodies)

      for trial <- 1..20 do
        pose =
          {x, y, th} = {:rand.uniform() * 4 - 2, :rand.uniform() * 4 - 2, :rand.uniform() * 7}

        groups =
          for _ <- 1..12 do
            %{
              x: :rand.uniform() * 0.4 - 0.2,
              y: :rand.uniform() * 0.4 - 0.2,
              heading: :rand.uniform() * 7 - 3.5,
              fov: Enum.random([0.0, 0.05, 0.3, 1.5, :math.pi(), 5.0, 2 * :math.pi()]),
              rays: Enum.random([1, 3, 8, 17, 64]),
              max_range: 4 + :rand.uniform() * 8
            }
          end

        got = readings(Raycast.scan(w, pose, Raycast.pack_groups(groups), trial, 0))

        for {g, reading} <- Enum.zip(groups, got) do
          {sx, sy} =
            {x + g.x * :math.cos(th) - g.y * :math.sin(th),
             y + g.x * :math.sin(th) + g.y * :math.cos(th)}

          rays =
            for k <- 0..(g.rays - 1),
                do: {sx, sy, th + g.heading - g.fov / 2 + (k + 0.5) * g.fov / g.rays, g.max_range}

          expected =
            Raycast.cast_rays(w, rays, exclude: trial) |> Enum.map(& &1.range) |> Enum.min()

          assert_in_delta reading, expected, @eps
        end
      end
    end

    test "in a grid among bodies, beams and reflecting cones read what cast_rays finds" do
      :rand.seed(:exsss, {7, 7, 7})
      grid = random_grid(300, 200, 0.05, {-7.5, -5.0, 0.3}, 0.02)
      w = world!(grid: grid)

      bodies =
        for _ <- 1..30,
            do: {:rand.uniform() * 12 - 6, :rand.uniform() * 8 - 4, 0.1 + :rand.uniform() * 0.3}

      :ok = Raycast.set_bodies(w, bodies)

      for trial <- 1..10 do
        pose =
          {x, y, th} = {:rand.uniform() * 4 - 2, :rand.uniform() * 4 - 2, :rand.uniform() * 7}

        # beams that echo every hit (one leg), and sonar cones that may bounce
        beams =
          for j <- 0..35,
              do: %{x: 0.1, heading: -1.6 + j * 0.09, max_range: 6.0}

        cones =
          for k <- 0..7 do
            %{
              x: 0.2 * :math.cos(k * 0.785),
              y: 0.2 * :math.sin(k * 0.785),
              heading: k * 0.785,
              fov: 0.26,
              rays: 3,
              max_range: 5.0,
              max_bounces: 2,
              critical_angle: 0.26
            }
          end

        groups = beams ++ cones
        got = readings(Raycast.scan(w, pose, Raycast.pack_groups(groups), trial, 0))

        for {g, reading} <- Enum.zip(groups, got) do
          {gx, gy} = {g.x, Map.get(g, :y, 0.0)}
          {fov, n} = {Map.get(g, :fov, 0.0), Map.get(g, :rays, 1)}

          {sx, sy} =
            {x + gx * :math.cos(th) - gy * :math.sin(th),
             y + gx * :math.sin(th) + gy * :math.cos(th)}

          rays =
            for k <- 0..(n - 1),
                do: {sx, sy, th + g.heading - fov / 2 + (k + 0.5) * fov / n, g.max_range}

          opts = [
            exclude: trial,
            max_bounces: Map.get(g, :max_bounces, 0),
            critical_angle: Map.get(g, :critical_angle, :math.pi() / 2)
          ]

          expected =
            Raycast.cast_rays(w, rays, opts)
            |> Enum.map(&if(&1.hit == :none, do: g.max_range, else: &1.range))
            |> Enum.min()

          assert_in_delta reading, expected, @eps
        end
      end
    end

    test "beams grazing bodies all around (every direction, ±x axis included) see them" do
      w = world!([])
      # a ring of bodies around the robot at (1, 2), one every 22.5°; the
      # sensor sits off the robot's centre; beams pass each body's centre
      # at 0.95 of its radius, on both sides, others just miss it
      r = 0.2

      centres =
        for k <- 0..15,
            do: {1 + 3 * :math.cos(k * :math.pi() / 8), 2 + 3 * :math.sin(k * :math.pi() / 8)}

      :ok = Raycast.set_bodies(w, [{1, 2, 0.3} | for({x, y} <- centres, do: {x, y, r})])

      for theta <- [0.0, :math.pi(), -:math.pi() / 2, 0.3, 2.0] do
        {sx, sy} =
          {1 + 0.2 * :math.cos(theta) - 0.1 * :math.sin(theta),
           2 + 0.2 * :math.sin(theta) + 0.1 * :math.cos(theta)}

        beams =
          for {cx, cy} <- centres, side <- [-1, 1], miss <- [false, true] do
            d = :math.sqrt((cx - sx) ** 2 + (cy - sy) ** 2)
            phi = :math.asin(if(miss, do: 1.02, else: 0.95) * r / d)
            a = :math.atan2(cy - sy, cx - sx) + side * phi

            expected =
              if miss,
                do: 5.0,
                else: d * :math.cos(phi) - :math.sqrt(r * r - (d * :math.sin(phi)) ** 2)

            {%{x: 0.2, y: 0.1, heading: a - theta, max_range: 5.0}, expected}
          end

        {groups, expected} = Enum.unzip(beams)
        got = readings(Raycast.scan(w, {1, 2, theta}, Raycast.pack_groups(groups), 0, 0))
        for {g, e} <- Enum.zip(got, expected), do: assert_in_delta(g, e, 1.0e-9)
      end
    end

    test "groups that do not add up to their header, or reach past its rays, are refused",
         %{world: w} do
      packed = Raycast.pack_groups([%{max_range: 5.0, rays: 3, max_bounces: 2}])
      assert Raycast.ray_budget(packed) == 9
      assert byte_size(Raycast.scan(w, {0, 0, 0}, packed, -1, 0)) == 8

      # a header claiming fewer rays than the groups hold (a long scan
      # passed off as short)
      <<head::binary-size(12), 9::native-32, rest::binary>> = packed
      lying = <<head::binary, 1::native-32, rest::binary>>
      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, lying, -1, 0) end

      # the group's rays start at 1 of 3: its last ray is past the end
      <<head::binary-size(64), 0.0::float-native-64, rest::binary>> = packed
      past = <<head::binary, 1.0::float-native-64, rest::binary>>
      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, past, -1, 0) end
      assert_raise ArgumentError, fn -> Raycast.scan_list(w, {0, 0, 0}, past, -1, 0) end

      # two rays from half a ray in: within the binary, and adding up to a
      # header that says 6, but not a whole ray
      <<head::binary-size(12), 9::native-32, groups::binary-size(40), 3.0::float-native-64,
        0.0::float-native-64, rest::binary>> = packed

      half =
        <<head::binary, 6::native-32, groups::binary, 2.0::float-native-64, 0.5::float-native-64,
          rest::binary>>

      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, half, -1, 0) end

      # a crosstalk ring no int holds (its conversion would be undefined)
      <<head::binary-size(104), -1.0::float-native-64, rest::binary>> = packed

      for ring <- [1.0e300, -2.0] do
        bad = <<head::binary, ring::float-native-64, rest::binary>>
        assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, bad, -1, 0) end
      end
    end

    test "a large scan (dirty scheduler) gives the same reading as cast_rays", %{world: w} do
      g = %{max_range: 5.0, heading: 0.4, fov: 0.5, rays: 5000}
      packed = Raycast.pack_groups([g])
      assert Raycast.ray_budget(packed) == 5000

      rays = for k <- 0..4999, do: {0, 0, 0.4 - 0.25 + (k + 0.5) * 0.5 / 5000, 5.0}
      expected = Raycast.cast_rays(w, rays) |> Enum.map(& &1.range) |> Enum.min()
      assert_in_delta scan1(w, {0, 0, 0}, packed), expected, @eps
      assert_in_delta expected, 2 / :math.cos(0.15 + 0.25 / 5000), 1.0e-9
    end

    test "bad groups are refused", %{world: w} do
      assert_raise ArgumentError, ~r/max_range/, fn -> Raycast.pack_groups([%{}]) end

      assert_raise ArgumentError, ~r/rays/, fn ->
        Raycast.pack_groups([%{max_range: 1, rays: 0}])
      end

      assert_raise ArgumentError, ~r/dropout/, fn ->
        Raycast.pack_groups([%{max_range: 1, dropout: 1.5}])
      end

      assert_raise ArgumentError, ~r/fov/, fn ->
        Raycast.pack_groups([%{max_range: 1, fov: :wide}])
      end

      assert_raise ArgumentError, ~r/unknown/, fn ->
        Raycast.pack_groups([%{max_range: 1, colour: 1}])
      end

      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, "garbage", -1, 0) end
      g = Raycast.pack_groups([%{max_range: 1}])

      assert_raise ArgumentError, fn ->
        Raycast.scan(w, {0, 0, 0}, binary_part(g, 0, 100), -1, 0)
      end

      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, :a, 0}, g, -1, 0) end
      assert_raise ArgumentError, fn -> Raycast.scan(w, {0, 0, 0}, g, -1, -5) end
    end
  end

  describe "clearance/5" do
    test "to a wall, capped at max, disabled walls do not count" do
      w = world!(segments: [{{2, -5}, {2, 5}}, {{-3, 0}, {-3, 10}}])
      assert_in_delta Raycast.clearance(w, 0, 0, -1, 10), 2.0, @eps
      # beyond the end of the second wall: distance to its end point
      assert_in_delta Raycast.clearance(w, -2, -1, -1, 10), :math.sqrt(2), @eps
      assert Raycast.clearance(w, 0, 0, -1, 1.5) == 1.5
      :ok = Raycast.set_segment(w, 0, false)
      assert_in_delta Raycast.clearance(w, 0, 0, -1, 10), 3.0, @eps
    end

    test "to the nearest point of an obstacle cell" do
      data = grid_data(10, 10, fn col, row -> col == 5 and row == 5 end)
      w = world!(grid: %{width: 10, height: 10, resolution: 0.1, origin: {0, 0, 0}, data: data})
      # the cell's lower-left corner
      assert_in_delta Raycast.clearance(w, 0.2, 0.2, -1, 5), :math.sqrt(0.18), @eps
      # its left face
      assert_in_delta Raycast.clearance(w, 0.2, 0.55, -1, 5), 0.3, @eps
      assert Raycast.clearance(w, 0.55, 0.55, -1, 5) == 0.0
      assert Raycast.clearance(w, 0.2, 0.2, -1, 0.1) == 0.1
      # from outside the grid
      assert_in_delta Raycast.clearance(w, -1.0, 0.55, -1, 5), 1.5, @eps
    end

    test "matches brute force in a rotated random grid" do
      :rand.seed(:exsss, {9, 9, 9})
      grid = random_grid(40, 30, 0.1, {0.5, -0.25, -2.0}, 0.03)
      w = world!(grid: grid)
      polygons = obstacle_polygons(grid)

      for _ <- 1..200 do
        pt = {-3.0 + :rand.uniform() * 4.5, -4.0 + :rand.uniform() * 4.0}

        unless (cell_at(grid, pt) || 0) >= 50 do
          expected = min(point_polygons(pt, polygons), 1.0)
          assert_in_delta Raycast.clearance(w, elem(pt, 0), elem(pt, 1), -1, 1.0), expected, @eps
        end
      end
    end

    test "to a body surface, the excluded body does not count" do
      w = world!([])
      :ok = Raycast.set_bodies(w, [{3, 0, 0.5}, {0, -2, 0.25}])
      assert_in_delta Raycast.clearance(w, 0, 0, -1, 10), 1.75, @eps
      assert_in_delta Raycast.clearance(w, 0, 0, 1, 10), 2.5, @eps
      assert Raycast.clearance(w, 3.1, 0, -1, 10) == 0.0
      assert Raycast.clearance(w, 0, 0, -1, 1) == 1.0
    end
  end

  describe "new/1 input" do
    test "accepts a RosMap struct and plain maps" do
      {:ok, map} = RosMap.load(Path.join(@maps, "testmap.yaml"))
      assert {:ok, _} = Raycast.new(grid: map)
      assert {:ok, _} = Raycast.new(grid: Map.from_struct(map), segments: [{{0, 0}, {1, 1}}])
      assert {:ok, _} = Raycast.new([])
    end

    test "bad input gives an error naming what is wrong" do
      grid = %{width: 2, height: 2, resolution: 0.1, origin: {0, 0, 0}, data: <<0, 0, 0, 0>>}
      assert {:ok, _} = Raycast.new(grid: grid)

      assert {:error, msg} = Raycast.new(grid: %{grid | data: <<0, 0, 0>>})
      assert msg =~ "data" and msg =~ "3 bytes"

      assert {:error, msg} = Raycast.new(segments: [{{0, 0}, {1, 1}}, {{0, :a}, {1, 1}}])
      assert msg =~ "segment 1"

      assert {:error, msg} = Raycast.new(segments: [{0, 0, 1, 1}])
      assert msg =~ "segment 0"

      assert {:error, msg} = Raycast.new(segments: [{{0, 0}, {1, 10 ** 400}}])
      assert msg =~ "segment 0"

      assert {:error, msg} = Raycast.new(segments: :walls)
      assert msg =~ "segments"

      assert {:error, msg} = Raycast.new(grid: %{grid | width: 0})
      assert msg =~ "width"

      assert {:error, msg} = Raycast.new(grid: %{grid | resolution: -1})
      assert msg =~ "resolution"

      assert {:error, msg} = Raycast.new(grid: %{grid | origin: {0, 0}})
      assert msg =~ "origin"

      assert {:error, msg} = Raycast.new(grid: Map.delete(grid, :data))
      assert msg =~ "missing data"

      assert {:error, msg} = Raycast.new(grid: "map.yaml")
      assert msg =~ "grid"

      assert {:error, msg} = Raycast.new(walls: [])
      assert msg =~ ":walls"

      assert {:error, _} = Raycast.new(:nope)
    end

    test "cast_rays refuses bad rays and options" do
      w = world!([])
      assert_raise ArgumentError, fn -> Raycast.cast_rays(w, [{0, 0, :a, 1}]) end
      assert_raise ArgumentError, fn -> Raycast.cast_rays(w, [{0, 0, 1}]) end
      assert_raise ArgumentError, fn -> Raycast.cast_rays(w, [], max_bounces: -1) end
      assert Raycast.cast_rays(w, []) == []
    end
  end

  test "concurrent casts see either body set, never a torn one" do
    w = world!(segments: [{{5, -5}, {5, 5}}])
    a = [{2, 0, 0.5}]
    b = [{3, 0, 0.5}]
    :ok = Raycast.set_bodies(w, a)

    casters =
      for _ <- 1..4 do
        Task.async(fn ->
          for _ <- 1..300, into: MapSet.new() do
            [%{range: r}] = Raycast.cast_rays(w, [{0, 0, 0, 10}])
            r
          end
        end)
      end

    for k <- 1..300, do: :ok = Raycast.set_bodies(w, if(rem(k, 2) == 0, do: a, else: b))

    seen = casters |> Enum.map(&Task.await/1) |> Enum.reduce(&MapSet.union/2)
    assert MapSet.subset?(seen, MapSet.new([1.5, 2.5]))
  end
end
