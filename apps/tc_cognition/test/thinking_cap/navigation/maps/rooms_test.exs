defmodule ThinkingCap.Navigation.Maps.RoomsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Maps, OccupancyGrid, Topology}
  alias ThinkingCap.Navigation.Maps.{Rooms, Segments}
  alias ThinkingCap.Testing.Sim, as: T

  @moduletag :tmp_dir

  # An occupancy grid of a world's walls: walls occupied, the rest free
  # (inside the outer walls) or unknown (outside them, margin cells).
  defp drawn(dir, walls, opts \\ []) do
    {:ok, wdf} = ThinkingCap.Config.read(T.wdf!(dir, walls: walls))
    grid = Maps.grid_from_wdf(wdf, resolution: 0.05, margin: 0.2)
    inside = Keyword.get(opts, :inside, fn {x, y} -> x > 0 and y > 0 and x < 8 and y < 4 end)

    data =
      for r <- 0..(grid.height - 1), c <- 0..(grid.width - 1), into: <<>> do
        {x, y} = ThinkingCap.Navigation.Grid.centre(grid, {c, r})

        cond do
          not ThinkingCap.Navigation.Grid.passable?(grid, {c, r}) -> <<100>>
          inside.({x, y}) -> <<0>>
          true -> <<-1::signed-8>>
        end
      end

    %OccupancyGrid{
      width: grid.width,
      height: grid.height,
      data: data,
      resolution: 0.05,
      origin: grid.origin
    }
  end

  # two 4 x 4 m rooms side by side, a door of `door` m between them at y = 2
  defp two_rooms(dir, door) do
    half = door / 2
    walls = T.box(8, 4) ++ [{{4, 0}, {4, 2 - half}}, {{4, 2 + half}, {4, 4}}]
    drawn(dir, walls)
  end

  test "two rooms and the door between them", %{tmp_dir: dir} do
    topology = Rooms.from_occupancy(two_rooms(dir, 0.9))

    assert Map.keys(topology.places) |> Enum.sort() == [:room_1, :room_2]
    %{room_1: west, room_2: east} = topology.places
    assert {west.kind, east.kind} == {:room, :room}
    {wx, wy} = west.centroid
    {ex, ey} = east.centroid
    assert_in_delta wx, 2.0, 0.15
    assert_in_delta ex, 6.0, 0.15
    assert_in_delta wy, 2.0, 0.15
    assert_in_delta ey, 2.0, 0.15

    assert [door] = Map.values(topology.doors)
    assert door.connects == [:room_1, :room_2]
    {dx, dy} = door.centre
    assert_in_delta dx, 4.0, 0.1
    assert_in_delta dy, 2.0, 0.1
    assert_in_delta door.width, 0.9, 0.15

    # the learned map routes like a drawn one
    assert {:ok, [%{place: :room_1}, %{place: :room_2, via_door: name}]} =
             Topology.route(topology, {1.0, 1.0}, {7.0, 3.0})

    assert name == door.name
    assert Topology.place_of(topology, {6.5, 1.0}) == :room_2
  end

  test "an opening wider than a door joins one room", %{tmp_dir: dir} do
    topology = Rooms.from_occupancy(two_rooms(dir, 2.0))
    assert [%{name: :room_1}] = Map.values(topology.places)
    assert topology.doors == %{}
  end

  test "a corridor is told from a room by its shape", %{tmp_dir: dir} do
    # a 10 x 1.6 m corridor above a 4 x 3 m room, joined by a 0.9 m door
    walls = [
      {{0, 0}, {4, 0}},
      {{4, 0}, {4, 3}},
      {{0, 0}, {0, 4.6}},
      {{0, 4.6}, {10, 4.6}},
      {{10, 4.6}, {10, 3}},
      {{10, 3}, {4, 3}},
      {{0, 3}, {1.55, 3}},
      {{2.45, 3}, {4, 3}}
    ]

    inside = fn {x, y} ->
      (x > 0 and x < 4 and y > 0 and y < 3) or (x > 0 and x < 10 and y > 3 and y < 4.6)
    end

    topology = Rooms.from_occupancy(drawn(dir, walls, inside: inside))
    kinds = topology.places |> Map.values() |> Enum.map(& &1.kind) |> Enum.sort()
    assert kinds == [:corridor, :room]
    assert [%{connects: [:corridor_1, :room_1]}] = Map.values(topology.doors)
  end

  test "names carry over as the map grows, and new places are numbered on", %{tmp_dir: dir} do
    small = Rooms.from_occupancy(two_rooms(dir, 0.9))
    renamed = Rooms.rename(small, small)
    assert Map.keys(renamed.places) == Map.keys(small.places)

    # the same world seen again: room_2 (east) is the only room seen before
    east_only = %{small | places: Map.take(small.places, [:room_2]), doors: %{}}

    again =
      Rooms.rename(small, %{
        east_only
        | places: %{room_7: %{east_only.places.room_2 | name: :room_7}}
      })

    assert Map.has_key?(again.places, :room_7)
    assert Topology.place_of(again, {6.0, 2.0}) == :room_7
    # the west room gets the next number
    assert Topology.place_of(again, {2.0, 2.0}) == :room_8
    assert [%{connects: connects}] = Map.values(again.doors)
    assert Enum.sort(connects) == [:room_7, :room_8]
  end

  test "the walls come out as fuzzy segments", %{tmp_dir: dir} do
    map = two_rooms(dir, 0.9)
    segments = Segments.from_occupancy(map)
    assert Enum.all?(segments, fn {_, _, degree} -> degree == 1.0 end)

    # each wall of the drawing is covered by segments within a cell of it
    for {{x1, y1}, {x2, y2}} = wall <- T.box(8, 4) ++ [{{4, 0}, {4, 1.55}}, {{4, 2.45}, {4, 4}}] do
      length = :math.sqrt((x2 - x1) ** 2 + (y2 - y1) ** 2)

      covered =
        segments
        |> Enum.filter(fn {a, b, _} ->
          Segments.distance(a, wall) < 0.1 and Segments.distance(b, wall) < 0.1
        end)
        |> Enum.map(fn {{ax, ay}, {bx, by}, _} -> :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2) end)
        |> Enum.sum()

      assert covered > 0.8 * length, "wall #{inspect(wall)}: #{covered} m of #{length} m covered"
    end
  end
end
