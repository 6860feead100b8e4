defmodule ThinkingCap.Sim.Core.WalkersTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim.Core.Walkers

  # the rule stated plainly: in order of id, each walker checks every
  # robot and every other walker as they stand so far
  defp brute_step(walkers, robots, dt) do
    walkers
    |> Enum.sort()
    |> Enum.reduce(walkers, fn {id, w}, acc ->
      others = for {o, %{at: {x, y}, radius: r}} <- acc, o != id, do: {x, y, r}
      Map.put(acc, id, brute_walker(w, others ++ robots, dt))
    end)
  end

  defp brute_walker(w, discs, dt) do
    {x, y} = w.at
    {tx, ty} = elem(w.route, w.leg)
    d = :math.sqrt((tx - x) ** 2 + (ty - y) ** 2)
    step = w.speed * dt

    cond do
      d <= step ->
        n = tuple_size(w.route)

        if (w.leg + w.dir) in 0..(n - 1),
          do: %{w | at: {tx, ty}, leg: w.leg + w.dir},
          else: %{w | at: {tx, ty}, leg: w.leg - w.dir, dir: -w.dir}

      Enum.all?(discs, fn {bx, by, r} ->
        nx = x + (tx - x) * step / d
        ny = y + (ty - y) * step / d
        (bx - nx) ** 2 + (by - ny) ** 2 > (r + w.radius + 0.05) ** 2
      end) ->
        %{w | at: {x + (tx - x) * step / d, y + (ty - y) * step / d}}

      true ->
        w
    end
  end

  test "crowded walkers among robots step as the plain rule says" do
    crowd_against_brute(0.1, 60, 20)
  end

  test "long steps (a walker crosses buckets in one step) as the plain rule says" do
    crowd_against_brute(0.7, 25, 5)
  end

  test "a malformed step is refused" do
    walker =
      <<0.0::float-native-64, 0.0::float-native-64, 0.2::float-native-64, 1.0::float-native-64,
        0.0::float-native-64, 1.0::float-native-64>>

    assert byte_size(ThinkingCap.Sim.Raycast.walkers_step(<<>>, walker, 0.1, 0.05)) == 24

    for {robots, walkers, dt} <- [
          {<<1.0::float-native-64>>, walker, 0.1},
          {<<>>, binary_part(walker, 0, 40), 0.1},
          {<<>>, walker, -0.1},
          {<<0.0::float-native-64, 0.0::float-native-64, -1.0::float-native-64>>, walker, 0.1}
        ] do
      assert_raise ArgumentError, fn ->
        ThinkingCap.Sim.Raycast.walkers_step(robots, walkers, dt, 0.05)
      end
    end
  end

  defp crowd_against_brute(dt, steps, min_waits) do
    rng = :rand.seed_s(:exsss, {4, 5, 6})

    point = fn rng ->
      {u, rng} = :rand.uniform_s(rng)
      {v, rng} = :rand.uniform_s(rng)
      {{u * 12, v * 12}, rng}
    end

    {walkers, rng} =
      Enum.map_reduce(1..80, rng, fn k, rng ->
        {a, rng} = point.(rng)
        {b, rng} = point.(rng)
        {c, rng} = point.(rng)
        {u, rng} = :rand.uniform_s(rng)

        w = %{
          at: a,
          route: {a, b, c},
          leg: 1,
          dir: 1,
          loop: false,
          speed: 0.5 + u,
          radius: 0.1 + u / 4
        }

        {{k, w}, rng}
      end)

    {robots, _rng} =
      Enum.map_reduce(0..59, rng, fn i, rng ->
        {{x, y}, rng} = point.(rng)
        {{i, x, y, 0.2 + rem(i, 3) * 0.1}, rng}
      end)

    discs = for {_, x, y, r} <- robots, do: {x, y, r}

    {fast, slow, waits} =
      Enum.reduce(1..steps, {Map.new(walkers), Map.new(walkers), 0}, fn _, {fast, slow, waits} ->
        fast2 = Walkers.step(fast, discs, dt)
        slow2 = brute_step(slow, discs, dt)
        assert fast2 == slow2
        {fast2, slow2, waits + Enum.count(fast2, fn {id, w} -> w.at == fast[id].at end)}
      end)

    assert fast == slow
    # walkers did wait for each other and for robots
    assert waits > min_waits
  end
end
