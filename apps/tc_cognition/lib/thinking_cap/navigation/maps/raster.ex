defmodule ThinkingCap.Navigation.Maps.Raster do
  @moduledoc false
  # Rasterization by row spans: a shape becomes, for each grid row it
  # touches, the inclusive column ranges `{c0, c1}` it covers
  # (`%{row => [{c0, c1}]}`); spans are merged, subtracted and painted into
  # row binaries, so a large grid is built from a few binary copies per row
  # and never cell by cell.
  #
  # Coordinates here are in cell units: `u = (x - ox) / resolution`, cell
  # `{c, r}` covering `[c, c + 1] × [r, r + 1]`.

  @eps 1.0e-9

  @type spans :: %{integer() => [{integer(), integer()}]}
  @type geometry :: {float(), float(), float(), pos_integer(), pos_integer()}

  @doc false
  @spec to_cells(geometry(), {number(), number()}) :: {float(), float()}
  def to_cells({ox, oy, res, _w, _h}, {x, y}), do: {(x - ox) / res, (y - oy) / res}

  @doc false
  # every cell the closed segment touches, boundaries included
  @spec segment({float(), float()}, {float(), float()}) :: spans()
  def segment({u1, v1}, {u2, v2}) do
    {vmin, vmax} = {min(v1, v2), max(v1, v2)}
    r0 = ceil(vmin - @eps) - 1
    r1 = floor(vmax + @eps)

    for r <- r0..r1, interval = x_interval({u1, v1}, {u2, v2}, r), interval != nil, into: %{} do
      {xa, xb} = interval
      {r, [{ceil(xa - @eps) - 1, floor(xb + @eps)}]}
    end
  end

  # the x extent of the segment within the band y ∈ [r, r + 1] (closed)
  defp x_interval({u1, v1}, {u2, v2}, r) do
    {lo, hi} = {r - @eps, r + 1 + @eps}

    if abs(v2 - v1) < 1.0e-12 do
      if v1 >= lo and v1 <= hi, do: {min(u1, u2), max(u1, u2)}
    else
      ta = (lo - v1) / (v2 - v1)
      tb = (hi - v1) / (v2 - v1)
      {t0, t1} = {max(min(ta, tb), 0.0), min(max(ta, tb), 1.0)}

      if t0 <= t1 do
        xa = u1 + t0 * (u2 - u1)
        xb = u1 + t1 * (u2 - u1)
        {min(xa, xb), max(xa, xb)}
      end
    end
  end

  @doc false
  # the cells whose centre is inside the polygon, and every cell its edges touch
  @spec polygon([{float(), float()}]) :: spans()
  def polygon(points) do
    edges = Enum.zip(points, tl(points) ++ [hd(points)])
    vs = Enum.map(points, &elem(&1, 1))
    r0 = floor(Enum.min(vs))
    r1 = ceil(Enum.max(vs))

    fill =
      for r <- r0..r1, spans = scanline(edges, r + 0.5), spans != [], into: %{}, do: {r, spans}

    Enum.reduce(edges, fill, fn {a, b}, acc -> union(acc, segment(a, b)) end)
  end

  defp scanline(edges, yc) do
    xs =
      for {{u1, v1}, {u2, v2}} <- edges, (v1 <= yc and yc < v2) or (v2 <= yc and yc < v1) do
        u1 + (yc - v1) / (v2 - v1) * (u2 - u1)
      end

    xs
    |> Enum.sort()
    |> Enum.chunk_every(2, 2, :discard)
    |> Enum.flat_map(fn [xa, xb] ->
      {c0, c1} = {ceil(xa - 0.5 - @eps), floor(xb - 0.5 + @eps)}
      if c0 <= c1, do: [{c0, c1}], else: []
    end)
  end

  @doc false
  @spec union(spans(), spans()) :: spans()
  def union(a, b), do: Map.merge(a, b, fn _row, sa, sb -> sa ++ sb end)

  @doc false
  # a's cells that are not b's
  @spec subtract(spans(), spans()) :: spans()
  def subtract(a, b) do
    Map.new(a, fn {row, spans} ->
      case Map.fetch(b, row) do
        {:ok, cut} -> {row, minus(merge(spans), merge(cut))}
        :error -> {row, spans}
      end
    end)
  end

  defp minus([], _cut), do: []
  defp minus(spans, []), do: spans

  defp minus([{a0, a1} | rest] = spans, [{b0, b1} | cuts] = cut) do
    cond do
      b1 < a0 -> minus(spans, cuts)
      a1 < b0 -> [{a0, a1} | minus(rest, cut)]
      true -> left(a0, b0) ++ minus(right(a1, b1, rest), cut)
    end
  end

  defp left(a0, b0) when a0 < b0, do: [{a0, b0 - 1}]
  defp left(_a0, _b0), do: []
  defp right(a1, b1, rest) when a1 > b1, do: [{b1 + 1, a1} | rest]
  defp right(_a1, _b1, rest), do: rest

  @doc false
  # sorted, disjoint, non-adjacent spans
  @spec merge([{integer(), integer()}]) :: [{integer(), integer()}]
  def merge(spans) do
    spans
    |> Enum.sort()
    |> Enum.reduce([], fn
      {c0, c1}, [{p0, p1} | acc] when c0 <= p1 + 1 -> [{p0, max(p1, c1)} | acc]
      span, acc -> [span | acc]
    end)
    |> Enum.reverse()
  end

  @doc false
  # merged spans clipped to columns 0..w-1
  @spec clip([{integer(), integer()}], pos_integer()) :: [{integer(), integer()}]
  def clip(spans, w) do
    for {c0, c1} <- merge(spans), c1 >= 0, c0 < w, do: {max(c0, 0), min(c1, w - 1)}
  end

  @doc false
  # the cells of spans inside a w × h grid
  @spec cells(spans(), pos_integer(), pos_integer()) :: [{integer(), integer()}]
  def cells(spans, w, h) do
    for {row, row_spans} <- Enum.sort(spans),
        row >= 0 and row < h,
        {c0, c1} <- clip(row_spans, w),
        col <- c0..c1,
        do: {col, row}
  end

  @doc false
  # the row binary with the (clipped, merged) spans set to byte `value`
  @spec paint(binary(), [{integer(), integer()}], 0..255) :: binary()
  def paint(row, [], _value), do: row

  def paint(row, spans, value) do
    w = byte_size(row)

    {parts, pos} =
      Enum.reduce(clip(spans, w), {[], 0}, fn {c0, c1}, {parts, pos} ->
        {[fill(value, c1 - c0 + 1), binary_part(row, pos, c0 - pos) | parts], c1 + 1}
      end)

    IO.iodata_to_binary(Enum.reverse([binary_part(row, pos, w - pos) | parts]))
  end

  @doc false
  @spec fill(0..255, non_neg_integer()) :: binary()
  def fill(value, n), do: :binary.copy(<<value>>, n)

  @doc false
  # the runs of non-zero bytes of a row, as inclusive spans
  @spec runs(binary()) :: [{non_neg_integer(), non_neg_integer()}]
  def runs(row), do: runs(row, 0, byte_size(row), [])

  defp runs(_row, pos, w, acc) when pos >= w, do: Enum.reverse(acc)

  defp runs(row, pos, w, acc) do
    case :binary.match(row, <<1>>, scope: {pos, w - pos}) do
      :nomatch ->
        Enum.reverse(acc)

      {s, 1} ->
        case :binary.match(row, <<0>>, scope: {s, w - s}) do
          :nomatch -> Enum.reverse([{s, w - 1} | acc])
          {e, 1} -> runs(row, e, w, [{s, e - 1} | acc])
        end
    end
  end
end
