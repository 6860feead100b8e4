defmodule ThinkingCap.Test.LaserRoom do
  @moduledoc false
  # A 180-degree laser of 181 beams (8 m) cast at walls given as segments
  # {{x1, y1}, {x2, y2}}, from the laser's pose: a scan as the simulator
  # sends it, without noise.

  @beams 181

  @doc "The laser's number of beams."
  def beams, do: @beams

  def scan(walls, {x, y, th}) do
    inc = :math.pi() / (@beams - 1)

    ranges =
      for i <- 0..(@beams - 1) do
        a = th - :math.pi() / 2 + i * inc
        {dx, dy} = {:math.cos(a), :math.sin(a)}

        walls
        |> Enum.map(fn {{x1, y1}, {x2, y2}} ->
          hit({x, y}, {dx, dy}, {x1, y1}, {x2 - x1, y2 - y1})
        end)
        |> Enum.reject(&is_nil/1)
        |> Enum.min(fn -> 8.0 end)
        |> min(8.0)
      end

    %{
      ranges: ranges,
      angle_min: -:math.pi() / 2,
      angle_increment: inc,
      range_max: 8.0,
      range_min: 0.1
    }
  end

  defp hit({px, py}, {dx, dy}, {qx, qy}, {ex, ey}) do
    den = dx * ey - dy * ex

    if abs(den) < 1.0e-12 do
      nil
    else
      t = ((qx - px) * ey - (qy - py) * ex) / den
      u = ((qx - px) * dy - (qy - py) * dx) / den
      if t > 0 and u >= 0 and u <= 1, do: t, else: nil
    end
  end
end
