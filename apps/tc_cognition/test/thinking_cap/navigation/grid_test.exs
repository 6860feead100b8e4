defmodule ThinkingCap.Navigation.GridTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.Grid

  test "put sets and clears cells in any order, repeated, and skips those outside" do
    grid = Grid.new(7, 5)
    cells = [{6, 4}, {0, 0}, {3, 2}, {3, 2}, {-1, 2}, {7, 0}, {2, 5}, {1, 0}]
    blocked = Grid.put(grid, cells, true)

    for col <- 0..6, row <- 0..4 do
      assert Grid.passable?(blocked, {col, row}) == {col, row} not in cells
    end

    assert byte_size(blocked.cells) == 35
    cleared = Grid.put(blocked, [{3, 2}, {0, 0}], false)
    assert Grid.passable?(cleared, {3, 2}) and Grid.passable?(cleared, {0, 0})
    refute Grid.passable?(cleared, {6, 4})
    assert Grid.put(grid, [], true) == grid
  end

  test "put on a large grid copies it once, not once per cell" do
    # 40,000 cells on a 400 × 400 grid: per-cell copies would take minutes
    cells = for col <- 0..399, row <- 0..99, do: {col, row * 4}
    grid = Grid.put(Grid.new(400, 400), cells, true)
    assert Enum.count(:binary.bin_to_list(grid.cells), &(&1 == 1)) == 40_000
  end
end
