defmodule ThinkingCap.Sim.BodyIndexTest do
  # The ray caster keeps its bodies in a grid of buckets, so that a query
  # looks only at the bodies near it. These properties check every query
  # that sees bodies (cast_rays/3, scan/5, clearance/5) against brute force
  # over all bodies and walls, on random worlds (PropEr).
  use ExUnit.Case, async: true

  alias ThinkingCap.Sim.Raycast

  @eps 1.0e-9
  # a removed robot: where ThinkingCap.Sim parks it
  @far {1.0e9, 1.0e9, 0.0}

  ## generators

  defp world_gen do
    :proper_types.bind(
      :proper_types.oneof([0.5, 5.0, 50.0, 400.0]),
      fn s ->
        :proper_types.tuple([
          :proper_types.list(body_gen(s)),
          :proper_types.list(segment_gen(s)),
          :proper_types.list(ray_gen(s)),
          :proper_types.list(point_gen(s)),
          :proper_types.list(pose_gen(s))
        ])
      end,
      false
    )
  end

  # bodies spread over the world, or clustered near the origin (many per
  # bucket), or parked far away
  defp body_gen(s) do
    :proper_types.frequency([
      {8, :proper_types.tuple([coord(s), coord(s), :proper_types.float(0.0, 1.5)])},
      {3,
       :proper_types.tuple([
         :proper_types.float(-1.0, 1.0),
         :proper_types.float(-1.0, 1.0),
         :proper_types.float(0.0, 0.4)
       ])},
      {1, :proper_types.exactly(@far)}
    ])
  end

  defp segment_gen(s),
    do:
      :proper_types.tuple([
        :proper_types.tuple([coord(s), coord(s)]),
        :proper_types.tuple([coord(s), coord(s)])
      ])

  # origins may lie outside the bodies' extent
  defp ray_gen(s),
    do:
      :proper_types.tuple([
        coord(1.5 * s),
        coord(1.5 * s),
        :proper_types.float(-4.0, 4.0),
        :proper_types.float(0.0, 3.0 * s)
      ])

  defp point_gen(s),
    do: :proper_types.tuple([coord(1.5 * s), coord(1.5 * s), :proper_types.float(0.0, 2.0 * s)])

  defp pose_gen(s),
    do:
      :proper_types.tuple([
        coord(1.2 * s),
        coord(1.2 * s),
        :proper_types.float(-4.0, 4.0),
        :proper_types.float(0.1, 2.0 * s)
      ])

  defp coord(s), do: :proper_types.float(-s, s)

  ## brute force

  # nearest hit {t, kind} of a ray among all segments and bodies (the NIF's
  # rules: a ray starting inside a body hits it at 0)
  defp brute_hit({x, y, a, max}, segments, bodies, exclude) do
    {dx, dy} = {:math.cos(a), :math.sin(a)}

    seg_hits =
      for {{ax, ay}, {bx, by}} <- segments, t = seg_t(x, y, dx, dy, ax, ay, bx, by), t, do: t

    body_hits =
      for {{bx, by, r}, id} <- Enum.with_index(bodies),
          id != exclude,
          t = circle_t(x, y, dx, dy, bx, by, r),
          t,
          do: t

    Enum.min([max | seg_hits ++ body_hits])
  end

  defp seg_t(px, py, dx, dy, ax, ay, bx, by) do
    {ex, ey} = {bx - ax, by - ay}
    den = dx * ey - dy * ex

    if abs(den) < 1.0e-300 do
      nil
    else
      {wx, wy} = {ax - px, ay - py}
      t = (wx * ey - wy * ex) / den
      u = (wx * dy - wy * dx) / den
      if t >= 0 and u >= 0 and u <= 1, do: t
    end
  end

  defp circle_t(px, py, dx, dy, bx, by, r) do
    {mx, my} = {px - bx, py - by}
    b = mx * dx + my * dy
    c = mx * mx + my * my - r * r

    cond do
      c <= 0 -> 0.0
      b > 0 -> nil
      b * b - c < 0 -> nil
      true -> -b - :math.sqrt(b * b - c)
    end
  end

  defp brute_clearance({x, y, max}, segments, bodies, exclude) do
    seg =
      for {{ax, ay}, {bx, by}} <- segments do
        {ex, ey} = {bx - ax, by - ay}
        l2 = ex * ex + ey * ey
        u = if l2 > 0, do: min(max(((x - ax) * ex + (y - ay) * ey) / l2, 0.0), 1.0), else: 0.0
        :math.sqrt((x - ax - u * ex) ** 2 + (y - ay - u * ey) ** 2)
      end

    body =
      for {{bx, by, r}, id} <- Enum.with_index(bodies), id != exclude do
        max(:math.sqrt((x - bx) ** 2 + (y - by) ** 2) - r, 0.0)
      end

    Enum.min([max | seg ++ body])
  end

  defp close?(a, b), do: abs(a - b) <= @eps * (1 + abs(b))

  ## properties

  # 150 random worlds: 13-25 s alone, past the default minute on a
  # loaded machine
  @tag timeout: 180_000
  test "casts, scans and clearances agree with brute force on random worlds" do
    property =
      :proper.forall(world_gen(), fn {bodies, segments, rays, points, poses} ->
        {:ok, w} = Raycast.new(segments: segments)
        :ok = Raycast.set_bodies(w, bodies)
        n = length(bodies)
        exclude = if n > 0, do: rem(length(rays) * 7, n), else: -1

        casts =
          Enum.zip(rays, Raycast.cast_rays(w, rays, exclude: exclude))
          |> Enum.all?(fn {ray, got} ->
            close?(got.range, brute_hit(ray, segments, bodies, exclude))
          end)

        clearances =
          Enum.all?(points, fn {x, y, max} = p ->
            close?(
              Raycast.clearance(w, x, y, exclude, max),
              brute_clearance(p, segments, bodies, exclude)
            )
          end)

        # single-ray groups all around the robot, no noise: each reading is
        # the nearest hit of its beam
        scans =
          Enum.all?(poses, fn {x, y, th, max} ->
            headings = for k <- 0..23, do: k * :math.pi() / 12
            groups = Raycast.pack_groups(for h <- headings, do: %{heading: h, max_range: max})
            got = Raycast.scan_list(w, {x, y, th}, groups, exclude, 1)

            Enum.zip(headings, got)
            |> Enum.all?(fn {h, r} ->
              close?(r, brute_hit({x, y, th + h, max}, segments, bodies, exclude))
            end)
          end)

        casts and clearances and scans
      end)

    assert :proper.quickcheck(property, [
             {:numtests, 150},
             {:max_size, 150},
             {:on_output, fn _format, _args -> :ok end},
             :long_result
           ]) == true
  end

  test "bodies moved, added and removed between set_bodies are found where they are now" do
    {:ok, w} = Raycast.new([])
    :rand.seed(:exsss, {18, 1, 1})

    for round <- 1..20 do
      n = Enum.random([0, 1, 2, 50, 500])

      bodies =
        for i <- 0..(n - 1)//1 do
          if rem(i + round, 9) == 0,
            do: @far,
            else: {:rand.uniform() * 100 - 50, :rand.uniform() * 60 - 30, 0.2}
        end

      :ok = Raycast.set_bodies(w, bodies)

      for {x, y, r} <- bodies, r > 0 do
        # just outside its surface: nothing is farther than its surface
        assert Raycast.clearance(w, x + r + 0.005, y, -1, 0.01) <= 0.005 + 1.0e-9
        # a ray from 1 m west reaches it at 1 m - r unless another body is nearer
        [hit] = Raycast.cast_rays(w, [{x - 1.0, y, 0.0, 2.0}])
        assert hit.hit == :body and hit.range <= 1.0 - r + 1.0e-9
      end
    end
  end
end
