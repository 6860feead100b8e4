defmodule ThinkingCap.Sim.Core.ContactsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim.Core.Contacts
  alias ThinkingCap.Sim.Raycast

  defp move(i, {x, y}, {x2, y2}, r \\ 0.2),
    do: {i, {x * 1.0, y * 1.0}, {x2 * 1.0, y2 * 1.0, 0.0}, r}

  defp taken_back(moves) do
    moves
    |> Enum.map(fn {i, {x, y}, {x2, y2, _}, r} -> Raycast.move_record(i, x, y, x2, y2, r) end)
    |> Contacts.taken_back()
  end

  test "two robots that both moved into the gap between them are taken back" do
    moves = [move(0, {0, 0}, {0.05, 0}), move(1, {0.45, 0}, {0.4, 0}), move(2, {5, 5}, {5.05, 5})]
    assert taken_back(moves) == MapSet.new([0, 1])
  end

  test "touching without overlap, moving apart, or far apart is fine" do
    assert taken_back([move(0, {0, 0}, {0.05, 0}), move(1, {0.5, 0}, {0.45, 0})]) ==
             MapSet.new()

    # already overlapping (a teleport), moving apart
    assert taken_back([move(0, {0, 0}, {-0.05, 0}), move(1, {0.3, 0}, {0.3, 0})]) ==
             MapSet.new()

    assert taken_back([]) == MapSet.new()
  end

  test "matches brute force over all pairs among many robots" do
    :rand.seed(:exsss, {18, 2, 3})

    for _ <- 1..20 do
      moves =
        for i <- 0..199 do
          {x, y} = {:rand.uniform() * 20, :rand.uniform() * 20}
          a = :rand.uniform() * 7
          r = 0.1 + :rand.uniform() * 0.3
          move(i, {x, y}, {x + 0.3 * :math.cos(a), y + 0.3 * :math.sin(a)}, r)
        end

      brute =
        for {i, {ax, ay}, {ax2, ay2, _}, ar} <- moves,
            {j, {bx, by}, {bx2, by2, _}, br} <- moves,
            i != j,
            d2 = (ax2 - bx2) ** 2 + (ay2 - by2) ** 2,
            d2 < (ar + br) ** 2 and d2 < (ax - bx) ** 2 + (ay - by) ** 2,
            into: MapSet.new(),
            do: i

      assert MapSet.size(brute) > 0
      assert taken_back(moves) == brute
    end
  end
end
