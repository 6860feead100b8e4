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

  describe "refusals: each names the file and the place" do
    setup %{tmp_dir: dir} do
      File.write!(Path.join(dir, "ok.pgm"), "P5\n2 2\n255\n" <> <<0, 254, 205, 0>>)
      :ok
    end

    # the errors of loading `yaml` (written to dir/m.yaml), as strings
    defp refused(dir, yaml) do
      path = Path.join(dir, "m.yaml")
      File.write!(path, yaml)
      assert {:error, [_ | _] = errors} = RosMap.load(path)

      for e <- errors, do: assert(String.starts_with?(e.file, dir))

      Enum.map(errors, &to_string/1)
    end

    defp pgm_refused(dir, pgm) do
      File.write!(Path.join(dir, "i.pgm"), pgm)
      refused(dir, "image: i.pgm\nresolution: 0.1\norigin: [0, 0]\n")
    end

    test "a map in every accepted YAML form loads", %{tmp_dir: dir} do
      File.write!(Path.join(dir, "m.yaml"), """
      ---
      # a comment
      image: 'ok.pgm'   # the image
      resolution: "0.5"
      origin:
        - -1
        - 2.5e0
      negate: false
      mode: trinary
      ...
      """)

      assert {:ok, %RosMap{width: 2, height: 2, resolution: 0.5, origin: {-1.0, 2.5, 0.0}}} =
               RosMap.load(Path.join(dir, "m.yaml"))
    end

    test "YAML value errors, all at once, at their line and column", %{tmp_dir: dir} do
      errors =
        refused(dir, """
        image: ok.pgm
        resolution: -1
        origin: [0, x, 0]
        negate: 2
        occupied_thresh: 1.5
        free_thresh: .nan
        mode: scale
        """)

      m = Path.join(dir, "m.yaml")

      assert errors == [
               "#{m}:2:13: resolution: -1 m/cell is out of range (0.0001 to 100.0)",
               "#{m}:3:13: origin: expected a number, got \"x\"",
               "#{m}:4:9: negate: expected 0 or 1",
               "#{m}:5:18: occupied_thresh: 1.5 is not between 0 and 1",
               "#{m}:6:14: free_thresh: .nan is not a finite number",
               "#{m}:7:7: mode: mode \"scale\" is not supported (only \"trinary\" is)"
             ]
    end

    test "unknown, repeated and missing keys", %{tmp_dir: dir} do
      m = Path.join(dir, "m.yaml")

      assert refused(dir, "image: ok.pgm\nresolutoin: 1\norigin: [0, 0]\norigin: [1, 1]\n") == [
               "#{m}:0:0: missing resolution",
               "#{m}:2:1: unknown key \"resolutoin\": did you mean resolution? " <>
                 "(known: image, resolution, origin, negate, occupied_thresh, free_thresh, mode)",
               "#{m}:4:1: origin is given twice (first at line 3)"
             ]
    end

    test "YAML this reader does not take: nesting, anchors, tags, documents", %{tmp_dir: dir} do
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [[0, 0], 0]\n")
      assert e =~ ":3:10: origin: [ here"
      assert [e] = refused(dir, "image: ok.pgm\nresolution: &r 1\norigin: [0, 0]\n")
      assert e =~ ":2:13: resolution: & here"
      assert [e] = refused(dir, "image: !!str ok.pgm\nresolution: 1\norigin: [0, 0]\n")
      assert e =~ ":1:8: image: ! here"
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [0, 0]\n---\nimage: x\n")
      assert e =~ ":4:1: several YAML documents"
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [0, 0\n")
      assert e =~ ":3:14: origin: expected , or ]"
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [0, 0]\n  x: 1\n")
      assert e =~ ":4:3: an indented line"
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [0, 0]\n\tnegate: 1\n")
      assert e =~ ":4:1: a tab in the indentation"
      assert [e] = refused(dir, "image: \"ok.pgm\nresolution: 1\norigin: [0, 0]\n")
      assert e =~ ":1:8: image: " or e =~ ":1:8: a \" string not closed"
      assert hd(refused(dir, "- 1\n- 2\n")) =~ ":0:0: missing image"
    end

    test "invalid UTF-8, a huge YAML file, not a file", %{tmp_dir: dir} do
      assert [e] = refused(dir, "image: ok.pgm\nresolution: 1\norigin: [0, 0]\n# caf\xE9\n")
      assert e =~ "m.yaml:4:6: not UTF-8 text"
      assert [e] = refused(dir, String.duplicate("# padding\n", 10_000))
      assert e =~ "m.yaml:0:0: 100000 bytes: a map's YAML file is limited to 65536 bytes"
      File.mkdir_p!(Path.join(dir, "d.yaml"))
      assert {:error, [e]} = RosMap.load(Path.join(dir, "d.yaml"))
      assert to_string(e) =~ "d.yaml:0:0: the map's YAML file is not a regular file (directory)"
    end

    test "the image: missing, not a file, not a PGM", %{tmp_dir: dir} do
      assert [e] = refused(dir, "image: none.pgm\nresolution: 1\norigin: [0, 0]\n")
      assert e =~ "none.pgm:0:0: cannot read the map's image: no such file or directory"
      assert [e] = refused(dir, "image: .\nresolution: 1\norigin: [0, 0]\n")
      assert e =~ "the map's image is not a regular file (directory)"
      assert [e] = pgm_refused(dir, <<0x89, "PNG\r\n", 26, 10, 0, 0>>)
      assert e =~ "i.pgm:byte 0: a PNG image: a map image must be a binary 8-bit PGM (P5)"
      assert [e] = pgm_refused(dir, "P2\n1 1\n255\n0\n")
      assert e =~ "i.pgm:byte 0: an ASCII grey map (PGM P2): a map image must be"
      assert [e] = pgm_refused(dir, "hello")
      assert e =~ "i.pgm:byte 0: not a PGM image"
    end

    test "PGM headers are read strictly, with the byte offset", %{tmp_dir: dir} do
      assert [e] = pgm_refused(dir, "P5\n4 x\n255\n")
      assert e =~ "i.pgm:byte 5: height: expected a decimal number"
      assert [e] = pgm_refused(dir, "P5\n0 4\n255\n")
      assert e =~ "i.pgm:byte 3: width: must be at least 1"
      assert [e] = pgm_refused(dir, "P5\n4 4\n65535\n")
      assert e =~ "i.pgm:byte 12: maximum value 65535: only 8-bit maps (255) are read"
      assert [e] = pgm_refused(dir, "P5\n40000 40000\n255\n")
      assert e =~ "i.pgm:byte 14: 40000 x 40000 = 1600000000 cells: a map is limited to 100000000"
      assert [e] = pgm_refused(dir, "P5\n1234567890 1\n255\n")
      assert e =~ "i.pgm:byte 3: width: a number of over 9 digits"
      assert [e] = pgm_refused(dir, "P5\n4 4")
      assert e =~ "i.pgm:byte 6: the file ends in the PGM header, before the end of the height"

      assert [e] =
               pgm_refused(dir, "P5\n" <> String.duplicate("# comment\n", 1000) <> "1 1\n255\n\0")

      assert e =~ "i.pgm:byte 4096: the PGM header is longer than 4096 bytes"
    end

    test "truncated and oversized image data, with the byte offset", %{tmp_dir: dir} do
      assert [e] = pgm_refused(dir, "P5\n4 4\n255\n" <> <<0, 0>>)
      assert e =~ "i.pgm:byte 13: the image data ends after 2 of 16 bytes (4 x 4 pixels)"
      assert [e] = pgm_refused(dir, "P5\n1 1\n255\n" <> <<0, 1, 2>>)
      assert e =~ "i.pgm:byte 12: 2 bytes after the image data (1 x 1 pixels end here)"
    end
  end

  test "a WDF imports a map and reports a bad one at its yaml: key", %{tmp_dir: dir} do
    good = Path.join(dir, "w.wdf")
    File.write!(good, ~s([name: "w", map: [yaml: #{inspect(Path.join(@maps, "testmap.yaml"))}]]))
    assert {:ok, %{grid: %RosMap{width: 10}}} = Config.read(good)

    bad = Path.join(dir, "bad.wdf")
    File.write!(bad, ~s([\n  name: "w",\n  map: [yaml: "nowhere.yaml"]\n]))
    assert {:error, [error, map_error]} = Config.read(bad)
    assert to_string(error) == "#{bad}:3:15: map.yaml: the map \"nowhere.yaml\" is refused:"

    assert to_string(map_error) ==
             "#{Path.join(dir, "nowhere.yaml")}:0:0: cannot read the map's YAML file: " <>
               "no such file or directory"
  end
end
