defmodule ThinkingCap.Navigation.OccupancyGridTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Grid, OccupancyGrid}

  @maps Path.expand("../../../../../priv/maps", __DIR__)

  @moduletag :tmp_dir

  test "a new map is unknown everywhere, and outside it too" do
    map = OccupancyGrid.new(3, 2, resolution: 0.1, origin: {1.0, 1.0})
    assert OccupancyGrid.value(map, {2, 1}) == -1
    assert OccupancyGrid.value(map, {3, 0}) == -1
    assert OccupancyGrid.cell_of(map, {1.25, 1.15}) == {2, 1}
  end

  test "a map_server map loads, converts to a planning grid and saves back", %{tmp_dir: dir} do
    assert {:ok, map} = OccupancyGrid.load(Path.join(@maps, "turtlebot3_world.yaml"))
    assert {map.width, map.height, map.origin} == {384, 384, {-10.0, -10.0}}
    # the map's corner is unknown, a point of its floor free
    assert OccupancyGrid.value(map, {0, 0}) == -1
    assert OccupancyGrid.value(map, OccupancyGrid.cell_of(map, {-2.0, -0.5})) == 0
    grid = OccupancyGrid.to_grid(map)
    refute Grid.passable?(grid, {0, 0})
    assert Grid.passable?(grid, OccupancyGrid.cell_of(map, {-2.0, -0.5}))
    assert Grid.passable?(OccupancyGrid.to_grid(map, unknown: :free), {0, 0})

    path = Path.join(dir, "saved.yaml")
    assert :ok = OccupancyGrid.save(map, path)
    assert {:ok, back} = OccupancyGrid.load(path)
    assert back.data == map.data
  end

  test "a map padded with unknown cells keeps its cells where they were in the world" do
    map = %{
      OccupancyGrid.new(2, 2, resolution: 0.5, origin: {1.0, 1.0})
      | data: <<0, 100, 50, 0>>
    }

    padded = OccupancyGrid.pad(map, 1, 2, 3, 1)
    assert {padded.width, padded.height, padded.origin} == {6, 5, {0.5, 0.0}}

    for {point, value} <- [{{1.2, 1.2}, 0}, {{1.7, 1.2}, 100}, {{1.2, 1.7}, 50}, {{0.7, 0.2}, -1}] do
      assert OccupancyGrid.value(padded, OccupancyGrid.cell_of(padded, point)) == value
    end
  end

  # rows drawn top first: . free, # occupied, ? unknown, o 40, f 15, w 80
  defp drawn(rows) do
    cells = for row <- Enum.reverse(rows), <<ch <- row>>, into: <<>>, do: <<cell(ch)::signed-8>>
    %{OccupancyGrid.new(byte_size(hd(rows)), length(rows)) | data: cells}
  end

  defp cell(?.), do: 0
  defp cell(?#), do: 100
  defp cell(??), do: -1
  defp cell(?o), do: 40
  defp cell(?f), do: 15
  defp cell(?w), do: 80

  test "a map drawn crisp for saving: walls thinned to the surfaces seen, the margin filled" do
    # a wall three cells thick before unknown space: its face towards the
    # free room is taken off, two cells stay
    assert OccupancyGrid.crisp(drawn(["...###??", "...###??"])) ==
             drawn(["....##??", "....##??"])

    # two cells between free space on both sides, and a wall of one cell,
    # stay whole
    assert OccupancyGrid.crisp(drawn(["..##..#..", "..##..#.."])) ==
             drawn(["..##..#..", "..##..#.."])

    # three cells between free space on both sides: the middle one stays
    assert OccupancyGrid.crisp(drawn(["..###..", "..###.."])) ==
             drawn(["...#...", "...#..."])

    # the unknown band the map builder's margin leaves before a wall is
    # free; unknown space with no wall beside it (a frontier) stays unknown
    assert OccupancyGrid.crisp(drawn(["..?#", "..??", "..??"])) ==
             drawn(["...#", "...?", "..??"])

    # values between the trinary thresholds are unknown, the others
    # rounded to free and occupied
    assert OccupancyGrid.crisp(drawn(["f?o?w"])) == drawn([".???#"])
  end

  test "a map shrunk for display keeps its obstacles and its frame" do
    # 4 x 2: an obstacle in the second block, the third block unknown
    data = <<0, 0, 0, 100, -1::signed-8, -1::signed-8, 0, 0, 0, 0, -1::signed-8, -1::signed-8>>
    map = %{OccupancyGrid.new(6, 2, resolution: 0.1, origin: {1.0, 2.0}) | data: data}
    assert OccupancyGrid.shrink(map, 12) == map
    small = OccupancyGrid.shrink(map, 3)
    assert {small.width, small.height, small.resolution, small.origin} == {3, 1, 0.2, {1.0, 2.0}}
    assert small.data == <<0, 100, -1::signed-8>>

    assert OccupancyGrid.shrink(%{map | data: :binary.copy(<<-1::signed-8>>, 12)}, 3).data ==
             :binary.copy(<<-1::signed-8>>, 3)
  end

  test "unknown cells are blocked by default and passable on request" do
    map = %{OccupancyGrid.new(2, 1) | data: <<-1::signed-8, 70>>}
    assert OccupancyGrid.to_grid(map).cells == <<1, 1>>
    assert OccupancyGrid.to_grid(map, unknown: :free).cells == <<0, 1>>
    assert OccupancyGrid.to_grid(map, unknown: :free, threshold: 80).cells == <<0, 0>>
  end

  test "a map whose origin is rotated is refused with its name", %{tmp_dir: _dir} do
    path = Path.join(@maps, "testmap.yaml")
    assert {:error, [error]} = OccupancyGrid.load(path)
    assert error.file == path and error.message =~ "yaw"
  end

  test "a missing or corrupt map file is an error naming it", %{tmp_dir: dir} do
    assert {:error, [error]} = OccupancyGrid.load(Path.join(dir, "none.yaml"))
    assert error.file == Path.join(dir, "none.yaml")
    yaml = Path.join(dir, "bad.yaml")
    File.write!(yaml, "image: bad.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    File.write!(Path.join(dir, "bad.pgm"), "P5\n10 10\n255\n\0\0")
    assert {:error, [error]} = OccupancyGrid.load(yaml)
    assert to_string(error) =~ "bad.pgm:byte 15: the image data ends after 2 of 100 bytes"
  end
end
