defmodule ThinkingCap.Sim.BuildingsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.RosMap
  alias ThinkingCap.Sim.Buildings

  @buildings [{1, {30, 20}}, {2, {40, 25}}, {3, {12, 8}}, {5, {8, 6}}, {11, {20, 35}}]

  defp building(seed, size) do
    {:ok, b} = Buildings.generate(seed: seed, size: size)
    b
  end

  defp cell(map, col, row) do
    <<_::binary-size(row * map.width + col), v::signed-8, _::binary>> = map.data
    v
  end

  defp to_cell(map, {x, y}), do: {floor(x / map.resolution), floor(y / map.resolution)}

  # how many free cells are reachable from `start` (4-connected)
  defp reachable(map, {c, r} = start) do
    seen = :atomics.new(map.width * map.height, [])
    :atomics.put(seen, r * map.width + c + 1, 1)
    flood(map, seen, [start], 1)
  end

  defp flood(_map, _seen, [], n), do: n

  defp flood(map, seen, frontier, n) do
    next =
      for {c, r} <- frontier,
          {nc, nr} = cell <- [{c + 1, r}, {c - 1, r}, {c, r + 1}, {c, r - 1}],
          nc in 0..(map.width - 1) and nr in 0..(map.height - 1),
          cell(map, nc, nr) == 0,
          :atomics.compare_exchange(seen, nr * map.width + nc + 1, 0, 1) == :ok,
          do: cell

    flood(map, seen, next, n + length(next))
  end

  defp free_count(map), do: for(<<v::signed-8 <- map.data>>, v == 0, reduce: 0, do: (n -> n + 1))

  # the opening measured on the raster: free cells along the wall through the door's centre
  # (the wall is two cells thick, centred on a cell boundary)
  defp opening(map, %{axis: axis, at: {x, y}}) do
    {c, r} = to_cell(map, {x, y})

    {step, cells} =
      case axis do
        :x ->
          s = round(y / map.resolution)
          {fn {c, r}, d -> {c + d, r} end, [{c, s - 1}, {c, s}]}

        :y ->
          s = round(x / map.resolution)
          {fn {c, r}, d -> {c, r + d} end, [{s - 1, r}, {s, r}]}
      end

    for start <- cells do
      run = fn d ->
        start
        |> Stream.iterate(&step.(&1, d))
        |> Enum.take_while(fn {c, r} -> cell(map, c, r) == 0 end)
        |> length()
      end

      (run.(1) + run.(-1) - 1) * map.resolution
    end
  end

  test "doors are 0.8 to 1.0 m wide, measured on the map" do
    for {seed, size} <- @buildings do
      b = building(seed, size)
      assert b.doors != []

      for door <- b.doors do
        assert door.width >= 0.8 - 1.0e-9 and door.width <= 1.0 + 1.0e-9
        for w <- opening(b.map, door), do: assert_in_delta(w, door.width, 1.0e-9)
      end
    end
  end

  test "every free cell is reachable from the start, and the outside is closed off" do
    for {seed, size} <- @buildings do
      %{map: map, start: start} = building(seed, size)
      from = to_cell(map, start)
      assert cell(map, elem(from, 0), elem(from, 1)) == 0
      assert reachable(map, from) == free_count(map), "seed #{seed}"

      # the border of the map is unknown, never free
      border = for c <- 0..(map.width - 1), r <- [0, map.height - 1], do: cell(map, c, r)

      assert Enum.all?(border, &(&1 == -1))
    end
  end

  test "a building has rooms, corridors, doors and furniture of realistic size" do
    b = building(1, {30, 20})
    assert length(b.rooms) >= 8
    assert b.corridors != []
    assert length(b.doors) >= length(b.rooms)
    assert length(b.furniture) >= length(b.rooms)

    assert Enum.all?(b.corridors, fn {x0, y0, x1, y1} -> min(x1 - x0, y1 - y0) >= 1.6 - 1.0e-9 end)

    # free space inside: most of the 600 m², not all of it
    free = free_count(b.map) * b.map.resolution ** 2
    assert free > 400 and free < 580
    assert b.map.resolution == 0.05
    assert {b.map.width, b.map.height} == {620, 420}
  end

  test "the same seed draws the same building; another seed another" do
    a = building(9, {25, 18})
    assert a == building(9, {25, 18})
    assert a.map.data != building(10, {25, 18}).map.data
  end

  @tag :tmp_dir
  test "saved as a map_server map, it loads back cell for cell", %{tmp_dir: dir} do
    b = building(4, {16, 12})
    path = Path.join(dir, "b4.yaml")
    :ok = Buildings.save(b, path)
    assert {:ok, map} = RosMap.load(path)
    assert map.data == b.map.data
    assert {map.width, map.height, map.resolution} == {b.map.width, b.map.height, 0.05}
  end

  test "bad options are refused, naming the problem" do
    assert {:error, m} = Buildings.generate(size: {3, 20})
    assert m =~ "size"
    assert {:error, m} = Buildings.generate(seed: "x")
    assert m =~ "seed"
    assert {:error, m} = Buildings.parse_size("30 by 20")
    assert m =~ "30 by 20"
    assert {:ok, {30.0, 20.5}} = Buildings.parse_size("30x20.5")
  end
end
