defmodule ThinkingCap.Navigation.ParticleFilterTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Navigation.{OccupancyGrid, ParticleFilter}
  alias ThinkingCap.Navigation.Core.GridNif

  # 4 x 4 m of 0.1 m cells: a wall along x = 3.0, the strip x < 1 unknown
  defp map do
    data =
      for r <- 0..39, c <- 0..39, into: <<>> do
        _ = r

        cond do
          c == 30 -> <<100::signed-8>>
          c < 10 -> <<-1::signed-8>>
          true -> <<0::signed-8>>
        end
      end

    %{OccupancyGrid.new(40, 40, resolution: 0.1) | data: data}
  end

  defp beams(list) do
    for {a, r} <- list,
        into: <<>>,
        do: <<0.0::float-native, 0.0::float-native, a::float-native, r::float-native>>
  end

  defp filter(strict) do
    ParticleFilter.new({1.5, 2.0, 0.0}, {0.1, 0.1}, range_max: 8.0)
    |> ParticleFilter.set_map(map(), 1, strict: strict)
  end

  test "beams ending on the wall fit; beams ending in the open do not" do
    pf = filter(true)
    pose = {1.5, 2.0, 0.0}
    # 1.5 m ahead is the wall; 0.5 m ahead is open floor 1 m from it
    assert {1.0, 10} = ParticleFilter.hits(pf, beams(List.duplicate({0.0, 1.5}, 10)), pose)
    assert {0.0, 10} = ParticleFilter.hits(pf, beams(List.duplicate({0.0, 0.5}, 10)), pose)
  end

  test "a beam without echo misfits where the map has a wall in its range" do
    pf = filter(true)
    pose = {1.5, 2.0, 0.0}
    # no echo towards the wall 1.5 m ahead: the laser would have seen it
    assert {0.0, 1} = ParticleFilter.hits(pf, beams([{0.0, 1.0e6}]), pose)
    # no echo towards the map's edge behind: nothing to judge by
    assert nil == ParticleFilter.hits(pf, beams([{:math.pi(), 1.0e6}]), pose)
  end

  test "a beam ending in unknown space, off the map or by the unknown's edge is not judged" do
    pose = {1.5, 2.0, 0.0}

    for strict <- [true, false] do
      # 1.0 m behind: inside the unknown strip (a box there, as the map
      # does not know); 0.45 m behind: in the open, 5 cm from the strip
      assert nil == ParticleFilter.hits(filter(strict), beams([{:math.pi(), 1.0}]), pose)
      assert nil == ParticleFilter.hits(filter(strict), beams([{:math.pi(), 0.45}]), pose)
      # 3 m ahead: off the map
      assert nil == ParticleFilter.hits(filter(strict), beams([{0.0, 3.0}]), pose)
    end

    # beside them, a beam in the open still misfits
    assert {0.0, 1} =
             ParticleFilter.hits(filter(true), beams([{:math.pi(), 1.0}, {0.0, 0.5}]), pose)
  end

  test "a wall seen once (occupancy under 50) counts from the threshold given" do
    # the wall along x = 3.0 at occupancy 40, as a first faint echo leaves it
    faint = %{map() | data: :binary.replace(map().data, <<100>>, <<40>>, [:global])}
    beam = beams([{0.0, 1.5}])
    pose = {1.5, 2.0, 0.0}

    pf = ParticleFilter.new(pose, {0.1, 0.1}, range_max: 8.0)
    # at the default 50 it is no wall: the beam ending on it misses
    assert {0.0, 1} = ParticleFilter.hits(ParticleFilter.set_map(pf, faint, 1), beam, pose)

    assert {1.0, 1} =
             ParticleFilter.hits(
               ParticleFilter.set_map(pf, faint, 1, threshold: 30),
               beam,
               pose
             )
  end

  test "a search of the map finds the pose a scan was taken from, its heading within a window" do
    pf = filter(true)
    # a scan from {2.0, 2.0, 0}: the wall 1 m ahead, fanned over ±0.6 rad
    scan = beams(for a <- -6..6, do: {a / 10, 1.0 / :math.cos(a / 10)})

    {_pf, {x, _y, th}} =
      ParticleFilter.relocalize(pf, scan, around: {{2.0, 2.0}, 0.6, {0.0, 0.3}})

    assert_in_delta x, 2.0, 0.1
    assert_in_delta th, 0.0, 0.1
  end

  test "a search leaves the particles be, and keeps the pose it is told to start from" do
    pf = filter(true)
    scan = beams(for a <- -6..6, do: {a / 10, 1.0 / :math.cos(a / 10)})
    {before, _} = ParticleFilter.estimate(pf)

    found = ParticleFilter.search(pf, scan, around: {{2.0, 2.0}, 0.6}, from: {2.5, 3.0, 1.0})

    assert [{best, x, _, th} | _] = found
    assert_in_delta x, 2.0, 0.1
    assert_in_delta th, 0.0, 0.1
    # best first, scored with the filter's sensor model
    assert best == found |> Enum.map(&elem(&1, 0)) |> Enum.max()
    assert best > ParticleFilter.score(pf, scan, {2.5, 3.0, 1.0})
    # the pose searched from is among the candidates (refined round itself)
    assert Enum.any?(found, fn {_, cx, cy, _} -> abs(cx - 2.5) < 0.6 and abs(cy - 3.0) < 0.6 end)
    assert {^before, _} = ParticleFilter.estimate(pf)
    assert ParticleFilter.echoes(pf, scan) == 13
  end

  test "the lattice keeps the poses that score best, as scoring each pose would" do
    pf = filter(true)
    # a few beams of every kind: on the wall, in the open, into the
    # unknown strip, off the map, without echo
    # (beyond 8 of them, the lattice drops poses that cannot make the best)
    fan = for a <- -6..6, do: {a / 10, 1.0 / :math.cos(a / 10)}
    other = [{0.4, 1.3}, {-0.5, 0.7}, {:math.pi(), 1.2}, {1.2, 6.0}, {2.0, 1.0e6}]
    scan = beams(fan ++ other ++ for(a <- 1..6, do: {a * 0.5, a * 0.4}))

    model = {0.3, 0.9, 0.1, 8.0}

    found = GridNif.field_search(pf.field, scan, model, 0.2, 36, 25, {0.0, 0.0, 4.0, 4.0})

    # every pose of the same lattice (every second cell from the second,
    # known free and 0.15 m or more from the wall), scored one by one
    every =
      for r <- 1..39//2, c <- 1..39//2, c >= 10 and abs(c - 30) >= 2, k <- 0..35 do
        {x, y, th} = {(c + 0.5) * 0.1, (r + 0.5) * 0.1, -:math.pi() + 2 * :math.pi() * k / 36}
        {ll, _} = GridNif.field_score(pf.field, scan, model, {x, y, th})
        ll
      end

    best = every |> Enum.sort(:desc) |> Enum.take(25)
    assert length(found) == 25

    for {{ll, _, _, _}, expected} <- Enum.zip(found, best),
        do: assert_in_delta(ll, expected, 1.0e-3)
  end

  test "a search round a point off the map finds only the poses it was given" do
    pf = filter(true)
    scan = beams(for a <- -6..6, do: {a / 10, 1.0 / :math.cos(a / 10)})

    assert [] =
             GridNif.field_search(
               pf.field,
               scan,
               {0.3, 0.9, 0.1, 8.0},
               0.2,
               36,
               5,
               {50.0, 50.0, 60.0, 60.0}
             )

    found = ParticleFilter.search(pf, scan, around: {{55.0, 55.0}, 3.0}, from: {2.0, 2.0, 0.0})
    assert [{_, x, _, _}] = found
    assert_in_delta x, 2.0, 0.1
  end

  test "a search refines the places it is given beside the lattice's" do
    pf = filter(true)
    scan = beams(for a <- -6..6, do: {a / 10, 1.0 / :math.cos(a / 10)})
    # a lattice far from the pose the scan was taken from; the place
    # given near it is refined onto it
    found = ParticleFilter.search(pf, scan, around: {{1.5, 0.5}, 0.3}, also: [{2.1, 2.1, 0.08}])

    assert [{_, x, y, th} | _] = found
    assert_in_delta x, 2.0, 0.05
    assert_in_delta th, 0.0, 0.05
    assert y > 1.0
  end

  test "the mode of a cloud split between two places stands at one of them" do
    pf = filter(true)
    {pf, _} = ParticleFilter.relocalize_to(pf, [{0.0, 1.5, 1.0, 0.0}, {-0.2, 2.5, 3.0, 0.0}])

    {{mx, my, _}, _} = ParticleFilter.estimate(pf)
    assert_in_delta mx, 2.0, 0.2
    assert_in_delta my, 2.0, 0.3

    {{x, y, _}, share} = ParticleFilter.mode(pf, 1.0)

    assert (abs(x - 1.5) < 0.2 and abs(y - 1.0) < 0.2) or
             (abs(x - 2.5) < 0.2 and abs(y - 3.0) < 0.2)

    assert share > 0.3 and share < 0.7
  end
end
