defmodule ThinkingCap.Navigation.AStarTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{AStar, Grid, MovingAI}

  @movingai Path.expand("../../../../../test/data/movingai", __DIR__)

  # rows given top first, as drawn; "#" blocked
  defp grid(rows, opts \\ []) do
    height = length(rows)
    width = String.length(hd(rows))

    cells =
      rows
      |> Enum.reverse()
      |> Enum.map(fn row -> for <<c <- row>>, into: <<>>, do: <<if(c == ?#, do: 1, else: 0)>> end)
      |> IO.iodata_to_binary()

    Grid.new(width, height, Keyword.put(opts, :cells, cells))
  end

  # every step to one of the 8 neighbours, every cell passable, no corner cut
  defp valid_path?(grid, path) do
    Enum.all?(path, &Grid.passable?(grid, &1)) and
      path
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.all?(fn [{c1, r1}, {c2, r2}] ->
        abs(c1 - c2) <= 1 and abs(r1 - r2) <= 1 and {c1, r1} != {c2, r2} and
          (c1 == c2 or r1 == r2 or
             (Grid.passable?(grid, {c2, r1}) and Grid.passable?(grid, {c1, r2})))
      end)
  end

  test "optimal on every problem of Moving AI's arena (160 problems)" do
    {:ok, grid} = MovingAI.load_map(Path.join(@movingai, "arena.map"))
    {:ok, problems} = MovingAI.load_scenarios(Path.join(@movingai, "arena.map.scen"))
    assert length(problems) == 160

    for p <- problems do
      assert {:ok, %{path: path, cost: cost, expanded: expanded}} =
               AStar.plan(grid, p.start, p.goal)

      assert abs(cost - p.optimal_length) < 1.0e-4,
             "#{inspect(p.start_xy)} → #{inspect(p.goal_xy)}: #{cost}, expected #{p.optimal_length}"

      assert hd(path) == p.start and List.last(path) == p.goal
      assert valid_path?(grid, path)
      assert AStar.cost(path) == cost
      assert expanded >= 1
    end
  end

  test "straight and diagonal steps cost 1 and √2" do
    g = Grid.new(10, 10)
    assert {:ok, %{cost: cost, path: path}} = AStar.plan(g, {0, 0}, {5, 0})
    assert cost == 5.0
    assert length(path) == 6
    assert {:ok, %{cost: cost}} = AStar.plan(g, {0, 0}, {3, 3})
    assert_in_delta cost, 3 * :math.sqrt(2), 1.0e-12
    assert {:ok, %{cost: cost}} = AStar.plan(g, {0, 0}, {7, 2})
    assert_in_delta cost, 5 + 2 * :math.sqrt(2), 1.0e-12
  end

  test "no corner cutting: a diagonal squeeze between two blocked cells is refused" do
    g =
      grid([
        "...",
        ".#.",
        "#.."
      ])

    # from the bottom-left region's {1, 0} to {0, 1}: the diagonal would
    # pass between {0, 0} and {1, 1}, both blocked
    assert {:ok, %{path: path, cost: cost}} = AStar.plan(g, {1, 0}, {0, 1})
    assert valid_path?(g, path)
    # every diagonal here touches the blocked centre: round it by six straight steps
    assert path == [{1, 0}, {2, 0}, {2, 1}, {2, 2}, {1, 2}, {0, 2}, {0, 1}]
    assert cost == 6.0

    # one blocked cell beside the diagonal is enough to refuse it
    g = grid(["..", "#."])
    assert {:ok, %{path: [{0, 1}, {1, 1}, {1, 0}], cost: 2.0}} = AStar.plan(g, {0, 1}, {1, 0})

    # fully walled squeeze: no path at all
    g = grid([".#", "#."])
    assert {:error, :no_path} = AStar.plan(g, {1, 0}, {0, 1})
  end

  test "blocked or outside start and goal" do
    g = grid(["...", ".#.", "..."])
    assert {:error, :blocked_start} = AStar.plan(g, {1, 1}, {0, 0})
    assert {:error, :blocked_goal} = AStar.plan(g, {0, 0}, {1, 1})
    assert {:error, :blocked_start} = AStar.plan(g, {-1, 0}, {0, 0})
    assert {:error, :blocked_goal} = AStar.plan(g, {0, 0}, {3, 0})
  end

  test "no path when the goal is walled off" do
    g =
      grid([
        ".....",
        "..###",
        "..#..",
        "..###"
      ])

    assert {:error, :no_path} = AStar.plan(g, {0, 0}, {4, 1})
    assert {:ok, %{path: [{3, 1}, {4, 1}]}} = AStar.plan(g, {3, 1}, {4, 1})
  end

  test "start equal to goal" do
    assert {:ok, %{path: [{2, 2}], cost: 0.0}} = AStar.plan(Grid.new(4, 4), {2, 2}, {2, 2})
  end

  test "goes round a wall by its gap" do
    g =
      grid([
        ".......",
        ".#####.",
        ".......",
        "######.",
        "......."
      ])

    assert {:ok, %{path: path, cost: cost}} = AStar.plan(g, {0, 0}, {0, 2})
    assert valid_path?(g, path)
    # east along the bottom to the gap, up through it, back west: no
    # diagonal is allowed at the gap's corners
    assert cost == 14.0
  end

  test "plan_world: world points in, cell centres out, length in metres" do
    g = Grid.new(20, 10, resolution: 0.5, origin: {-2.0, 1.0})
    assert {:ok, result} = AStar.plan_world(g, {-1.9, 1.1}, {2.2, 1.2})
    assert hd(result.cells) == {0, 0} and List.last(result.cells) == {8, 0}
    assert hd(result.path) == {-1.75, 1.25}
    assert List.last(result.path) == {2.25, 1.25}
    assert result.cost == 8.0
    assert result.length_m == 4.0
    assert AStar.path_length_m(g, result.cells) == 4.0
    assert {:error, :blocked_start} = AStar.plan_world(g, {-5.0, 0.0}, {1.0, 2.0})
  end

  test "path_length_m of a diagonal path" do
    g = Grid.new(5, 5, resolution: 0.1)

    assert_in_delta AStar.path_length_m(g, [{0, 0}, {1, 1}, {2, 1}]),
                    0.1 + 0.1 * :math.sqrt(2),
                    1.0e-12

    assert AStar.path_length_m(g, [{0, 0}]) == 0.0
  end

  test "Grid.update/2 sets many cells like put/3" do
    g = Grid.new(6, 4)
    changes = [{{0, 0}, true}, {{5, 3}, true}, {{2, 1}, true}, {{2, 1}, false}, {{9, 9}, true}]
    updated = Grid.update(g, changes)
    assert updated.cells == Grid.put(Grid.put(g, [{0, 0}, {5, 3}], true), [{2, 1}], false).cells
    refute Grid.passable?(updated, {0, 0})
    refute Grid.passable?(updated, {5, 3})
    assert Grid.passable?(updated, {2, 1})

    assert Grid.update(updated, [{{0, 0}, false}]).cells ==
             Grid.put(updated, [{0, 0}], false).cells

    assert Grid.update(g, []) == g
  end
end
