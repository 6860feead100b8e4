defmodule ThinkingCap.Navigation.MovingAITest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{Grid, MovingAI}

  @movingai Path.expand("../../../../../test/data/movingai", __DIR__)

  describe "maps" do
    test "arena: dimensions and known cells, rows counted from the bottom" do
      assert {:ok, %Grid{width: 49, height: 49} = grid} =
               MovingAI.load_map(Path.join(@movingai, "arena.map"))

      assert byte_size(grid.cells) == 49 * 49
      # the map's top row is all trees: the grid's row 48
      for x <- 0..48, do: refute(Grid.passable?(grid, MovingAI.to_cell(49, {x, 0})))
      refute Grid.passable?(grid, {0, 48})
      # second text row "TTT............TTTT.TTT...": (3, 1) open, (2, 1) and (15, 1) trees
      assert Grid.passable?(grid, MovingAI.to_cell(49, {3, 1}))
      assert Grid.passable?(grid, {3, 47})
      refute Grid.passable?(grid, {2, 47})
      refute Grid.passable?(grid, {15, 47})
      assert Grid.passable?(grid, {19, 47})
      # the trees of text rows 7-9 (x 23-25) in the middle of the open field
      refute Grid.passable?(grid, MovingAI.to_cell(49, {24, 7}))
      assert Grid.passable?(grid, MovingAI.to_cell(49, {22, 7}))
      assert grid.resolution == 1.0 and grid.origin == {0.0, 0.0}
    end

    test "maze512: dimensions and border" do
      assert {:ok, %Grid{width: 512, height: 512} = grid} =
               MovingAI.load_map(Path.join(@movingai, "maze512-32-9.map"))

      refute Grid.passable?(grid, {0, 0})
      refute Grid.passable?(grid, {511, 511})
      # second text row starts "@...."
      assert Grid.passable?(grid, MovingAI.to_cell(512, {1, 1}))
    end

    test "terrain: . G S passable, @ O T W blocked" do
      text = "type octile\nheight 2\nwidth 4\nmap\n.GS@\nOTW.\n"
      assert {:ok, grid} = MovingAI.parse_map(text)
      # text row 0 is grid row 1
      assert Enum.map(0..3, &Grid.passable?(grid, {&1, 1})) == [true, true, true, false]
      assert Enum.map(0..3, &Grid.passable?(grid, {&1, 0})) == [false, false, false, true]
    end

    test "CRLF line ends" do
      assert {:ok, %Grid{width: 2, height: 1}} =
               MovingAI.parse_map("type octile\r\nheight 1\r\nwidth 2\r\nmap\r\n.@\r\n")
    end

    test "errors name the file and the line" do
      header = "type octile\nheight 2\nwidth 3\nmap\n"

      assert {:error, "m.map:6: row of 2 cells, expected 3"} =
               MovingAI.parse_map(header <> "...\n..\n", "m.map")

      assert {:error, "m.map:5: unknown terrain \"x\""} =
               MovingAI.parse_map(header <> ".x.\n...\n", "m.map")

      assert {:error, "m.map:6: 1 map row(s) missing"} =
               MovingAI.parse_map(header <> "...\n", "m.map")

      assert {:error, "m.map: 1 map row(s) missing"} =
               MovingAI.parse_map(header <> "...", "m.map")

      assert {:error, "m.map:2: bad height \"two\""} =
               MovingAI.parse_map("type octile\nheight two\nwidth 3\nmap\n", "m.map")

      assert {:error, "m.map: no width in the header"} =
               MovingAI.parse_map("type octile\nheight 1\nmap\n.\n", "m.map")

      assert {:error, "m.map: no \"map\" line ending the header"} =
               MovingAI.parse_map("type octile\nheight 1\nwidth 1\n", "m.map")

      assert {:error, "m.map:1: bad header line" <> _} =
               MovingAI.parse_map("type octile map\n", "m.map")

      assert {:error, message} = MovingAI.load_map("/nonexistent/x.map")
      assert message =~ "/nonexistent/x.map"
    end
  end

  describe "scenarios" do
    test "arena: 160 problems, coordinates flipped to the grid's rows" do
      assert {:ok, problems} = MovingAI.load_scenarios(Path.join(@movingai, "arena.map.scen"))
      assert length(problems) == 160
      # "0	maps/dao/arena.map	49	49	1	13	4	12	3.41421"
      p = Enum.at(problems, 2)
      assert p.bucket == 0 and p.map == "maps/dao/arena.map"
      assert {p.width, p.height} == {49, 49}
      assert p.start_xy == {1, 13} and p.goal_xy == {4, 12}
      assert p.start == {1, 35} and p.goal == {4, 36}
      assert p.optimal_length == 3.41421
      assert List.last(problems).bucket == 15
    end

    test "maze512: 8010 problems" do
      assert {:ok, problems} =
               MovingAI.load_scenarios(Path.join(@movingai, "maze512-32-9.map.scen"))

      assert length(problems) == 8010
      assert %{bucket: 800, optimal_length: 3201.44696807} = List.last(problems)
    end

    test "errors name the file and the line" do
      assert {:error, "s.scen:1: expected \"version 1\"" <> _} =
               MovingAI.parse_scenarios("0\tm.map\t4\t4\t0\t0\t1\t1\t1.4\n", "s.scen")

      assert {:error, "s.scen:3: 8 fields, expected 9"} =
               MovingAI.parse_scenarios(
                 "version 1\n0\tm.map\t4\t4\t0\t0\t1\t1\t1.4\n0\tm.map\t4\t4\t0\t0\t1\t1\n",
                 "s.scen"
               )

      assert {:error, "s.scen:2: bad integer \"x\""} =
               MovingAI.parse_scenarios("version 1\n0\tm.map\t4\t4\tx\t0\t1\t1\t1.4\n", "s.scen")

      assert {:error, "s.scen:2: goal (4, 1) outside the 4×4 map"} =
               MovingAI.parse_scenarios("version 1\n0\tm.map\t4\t4\t0\t0\t4\t1\t3\n", "s.scen")

      assert {:error, "s.scen:2: bad optimal length \"long\""} =
               MovingAI.parse_scenarios("version 1\n0\tm.map\t4\t4\t0\t0\t1\t1\tlong\n", "s.scen")

      assert {:error, "s.scen:1: empty scenario file"} = MovingAI.parse_scenarios("", "s.scen")
    end
  end

  test "to_cell and to_xy are inverse" do
    for x <- 0..4, y <- 0..6 do
      assert MovingAI.to_xy(7, MovingAI.to_cell(7, {x, y})) == {x, y}
    end

    assert MovingAI.to_cell(7, {2, 0}) == {2, 6}
  end

  test "solve: A* on each problem, optimal against the file" do
    {:ok, grid} = MovingAI.parse_map("type octile\nheight 3\nwidth 3\nmap\n...\n.@.\n...\n")

    {:ok, problems} =
      MovingAI.parse_scenarios(
        "version 1\n0\tm\t3\t3\t0\t0\t2\t2\t4\n1\tm\t3\t3\t0\t0\t2\t0\t1\n"
      )

    # round the blocked centre: 4 (as the file says); along the top row: 2, not 1
    assert [%{optimal: true, cost: 4.0}, %{optimal: false, cost: 2.0}] =
             MovingAI.solve(grid, problems)

    assert [%{optimal: true}, %{optimal: false}] = MovingAI.solve(grid, problems, jobs: 2)
  end
end
