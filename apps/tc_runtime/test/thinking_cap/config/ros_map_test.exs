defmodule ThinkingCap.Config.RosMapTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config
  alias ThinkingCap.Config.RosMap

  @maps Path.expand("../../../../../priv/maps", __DIR__)

  @moduletag :tmp_dir

  test "testmap loads as the 10x10 grid the map_server rules give" do
    assert {:ok, grid} = RosMap.load(Path.join(@maps, "testmap.yaml"))

    assert {grid.width, grid.height, grid.resolution, grid.origin} ==
             {10, 10, 0.1, {2.0, 3.0, 1.0}}

    # pixel 0 (black) -> p = 1 > 0.65 -> occupied; 254 -> p = 1/255 < 0.196 -> free.
    # Grid row 0 is the picture's bottom row.
    assert RosMap.rows(grid) == [
             [0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
             [100, 100, 100, 100, 0, 0, 100, 100, 100, 0],
             [100, 100, 100, 100, 0, 0, 100, 100, 100, 0],
             [100, 0, 0, 0, 0, 0, 0, 0, 0, 0],
             [100, 0, 0, 0, 0, 0, 0, 0, 0, 0],
             [100, 0, 0, 0, 0, 0, 100, 100, 0, 0],
             [100, 0, 0, 0, 0, 0, 100, 100, 0, 0],
             [100, 0, 0, 0, 0, 0, 100, 100, 0, 0],
             [100, 0, 0, 0, 0, 0, 100, 100, 0, 0],
             [100, 0, 0, 0, 0, 0, 0, 0, 0, 0]
           ]

    assert RosMap.cell(grid, 0, 9) == 100
    assert RosMap.cell(grid, 9, 9) == 0
    assert RosMap.cell(grid, 6, 1) == 100
  end

  test "a saved map loads back identically", %{tmp_dir: dir} do
    for name <- ["testmap", "turtlebot3_world"] do
      {:ok, map} = RosMap.load(Path.join(@maps, name <> ".yaml"))
      yaml = Path.join(dir, name <> "_copy.yaml")
      assert :ok = RosMap.save(map, yaml)
      assert File.exists?(Path.join(dir, name <> "_copy.pgm"))
      assert {:ok, back} = RosMap.load(yaml)

      assert {back.width, back.height, back.resolution, back.origin, back.data} ==
               {map.width, map.height, map.resolution, map.origin, map.data}
    end
  end

  test "saving writes map_saver's trinary colours and thresholds", %{tmp_dir: dir} do
    # -1 unknown, 0 free, 19 free, 20 unknown, 64 unknown, 65 occupied, 100 occupied
    data = <<-1::signed-8, 0, 19, 20, 64, 65, 100, 0>>
    map = %{width: 4, height: 2, resolution: 0.1, origin: {1.0, 2.0}, data: data}
    yaml = Path.join(dir, "m.yaml")
    assert :ok = RosMap.save(map, yaml)
    # the image's first row is the grid's top row
    assert File.read!(Path.join(dir, "m.pgm")) =~ ~r/^P5\n(#[^\n]*\n)?4 2\n255\n/

    assert binary_part(
             File.read!(Path.join(dir, "m.pgm")),
             byte_size(File.read!(Path.join(dir, "m.pgm"))) - 8,
             8
           ) ==
             <<205, 0, 0, 254, 205, 254, 254, 205>>

    assert {:ok, back} = RosMap.load(yaml)
    assert RosMap.rows(back) == [[-1, 0, 0, -1], [-1, 100, 100, 0]]
    assert back.origin == {1.0, 2.0, 0.0}
  end

  test "saving a map whose data does not fit its size is refused", %{tmp_dir: dir} do
    yaml = Path.join(dir, "bad.yaml")
    map = %{width: 3, height: 3, resolution: 0.1, origin: {0, 0}, data: <<0, 0>>}
    assert {:error, message} = RosMap.save(map, yaml)
    assert message =~ "bad.yaml"
    refute File.exists?(yaml)
  end

  test "the nav2 maps load with their size, resolution and origin" do
    for {name, size, resolution, origin} <- [
          {"turtlebot3_world", {384, 384}, 0.05, {-10.0, -10.0, 0.0}},
          {"depot", {604, 307}, 0.05, {0.0, 0.0, 0.0}},
          {"warehouse", {1006, 1674}, 0.03, {-15.1, -25.0, 0.0}}
        ] do
      assert {:ok, grid} = RosMap.load(Path.join(@maps, name <> ".yaml"))

      assert {{grid.width, grid.height}, grid.resolution, grid.origin} ==
               {size, resolution, origin}

      assert byte_size(grid.data) == grid.width * grid.height

      values =
        grid.data
        |> :binary.bin_to_list()
        |> Enum.uniq()
        |> Enum.map(&if(&1 > 127, do: &1 - 256, else: &1))

      assert Enum.sort(values) -- [-1, 0, 100] == []
      assert 100 in values and 0 in values
    end
  end

  test "negate flips the reading of pixels", %{tmp_dir: dir} do
    File.cp!(Path.join(@maps, "testmap.pgm"), Path.join(dir, "m.pgm"))

    File.write!(
      Path.join(dir, "m.yaml"),
      "image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 1\n"
    )

    assert {:ok, grid} = RosMap.load(Path.join(dir, "m.yaml"))
    # black is free now, 254 occupied
    assert RosMap.cell(grid, 0, 9) == 0
    assert RosMap.cell(grid, 9, 9) == 100
  end

  test "header comments in the PGM are skipped", %{tmp_dir: dir} do
    File.write!(Path.join(dir, "c.pgm"), "P5\n# made by hand\n2 1\n# max\n255\n" <> <<0, 254>>)
    File.write!(Path.join(dir, "c.yaml"), "image: c.pgm\nresolution: 1\norigin: [0, 0, 0]\n")
    assert {:ok, %RosMap{width: 2, height: 1} = grid} = RosMap.load(Path.join(dir, "c.yaml"))
    assert RosMap.rows(grid) == [[100, 0]]
  end

  test "bad map files get errors naming the file and the problem", %{tmp_dir: dir} do
    yaml = fn name, text -> File.write!(Path.join(dir, name), text) && Path.join(dir, name) end
    File.write!(Path.join(dir, "ascii.pgm"), "P2\n1 1\n255\n0\n")
    File.write!(Path.join(dir, "short.pgm"), "P5\n4 4\n255\n" <> <<0, 0>>)

    assert {:error, m} =
             RosMap.load(
               yaml.("a.yaml", "image: ascii.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
             )

    assert m =~ "ascii.pgm: expected a binary PGM image (P5), found magic \"P2\""

    assert {:error, m} =
             RosMap.load(
               yaml.("b.yaml", "image: short.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
             )

    assert m =~ "short.pgm: expected 16 pixels (4x4), found 2"

    assert {:error, m} =
             RosMap.load(yaml.("c.yaml", "image: none.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n"))

    assert m =~ "cannot read #{Path.join(dir, "none.pgm")}: no such file or directory"

    assert {:error, m} =
             RosMap.load(yaml.("d.yaml", "image: short.pgm\nresolution: -1\norigin: [0, 0, 0]\n"))

    assert m =~ "d.yaml: resolution: expected a positive number (m/cell), got -1"

    assert {:error, m} =
             RosMap.load(yaml.("e.yaml", "image: short.pgm\norigin: [0, 0]\nresolution: 1\n"))

    assert m =~ "e.yaml: origin: expected [x, y, yaw], got [0, 0]"

    assert {:error, m} =
             RosMap.load(
               yaml.("f.yaml", "image: x.pgm\nresolution: 1\norigin: [0, 0, 0]\nmode: scale\n")
             )

    assert m =~ "f.yaml: mode \"scale\" is not supported (only \"trinary\" is)"
    assert {:error, m} = RosMap.load(yaml.("g.yaml", "image: [unclosed\n"))
    assert m =~ "g.yaml: invalid YAML"
  end

  test "a WDF imports a map and reports a bad one at its yaml: key", %{tmp_dir: dir} do
    good = Path.join(dir, "w.wdf")
    File.write!(good, ~s([name: "w", map: [yaml: #{inspect(Path.join(@maps, "testmap.yaml"))}]]))
    assert {:ok, %{grid: %RosMap{width: 10}}} = Config.read(good)

    bad = Path.join(dir, "bad.wdf")
    File.write!(bad, ~s([\n  name: "w",\n  map: [yaml: "nowhere.yaml"]\n]))
    assert {:error, [error]} = Config.read(bad)

    assert to_string(error) =~
             "bad.wdf:3:15: map.yaml: cannot read #{Path.join(dir, "nowhere.yaml")}"
  end
end
