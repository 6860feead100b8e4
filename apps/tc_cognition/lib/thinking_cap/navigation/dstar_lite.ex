defmodule ThinkingCap.Navigation.DStarLite do
  @moduledoc """
  Incremental replanning on a `ThinkingCap.Navigation.Grid` with D* Lite
  (S. Koenig and M. Likhachev, "D* Lite", AAAI 2002: the optimized version
  of their figure 4), for a robot that moves towards a goal while the
  cells around it change.

  The cost model is `ThinkingCap.Navigation.AStar`'s: 8-connected, a
  straight step costs 1 and a diagonal one √2, no corner cutting (a
  diagonal step needs both orthogonal cells it passes between passable),
  octile heuristic, exact integer arithmetic. Every plan is optimal: it
  costs what A* finds from scratch on the current grid.

  The search runs backwards, from the goal towards the robot: g-scores
  are distances to the goal, so when cells change only the vertices whose
  distance changed, and that matter to the robot's current cell, are
  processed again; when the robot moves (`move_start/2`), the key modifier
  `km` keeps the queued priorities valid without reordering the queue.

      state = DStarLite.new(grid, start, goal)
      {:ok, path, state} = DStarLite.plan(state)
      state = DStarLite.move_start(state, Enum.at(path, 3))
      state = DStarLite.update_cells(state, [{{12, 7}, true}])   # an obstacle
      {:ok, path, state} = DStarLite.plan(state)                # repaired

  ## The state is single-use

  The g- and rhs-values and queue keys live in an `:atomics` array shared
  by a state and the states derived from it, so only the state returned
  by the last call is valid: passing an older one raises `ArgumentError`.
  The priority queue is a pairing heap with lazy deletion (an entry is
  live while it matches the key recorded for its cell), compacted now and
  then. Costs must stay below 2^22 cells (the integer units are 2^-36
  cell; infinity is 2^58 units).
  """

  import Bitwise

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Core.{Cost, PairingHeap}

  require Cost

  @s Cost.straight()
  @d Cost.diagonal()
  @inf 1 <<< 58

  # the store: per cell g, rhs (as ∞ - value, so that 0 is ∞), key
  defmacrop g(a, i), do: quote(do: @inf - :atomics.get(unquote(a), 3 * unquote(i) + 1))
  defmacrop rhs(a, i), do: quote(do: @inf - :atomics.get(unquote(a), 3 * unquote(i) + 2))

  @enforce_keys [:grid, :start, :goal, :store, :version]
  defstruct [:grid, :start, :goal, :store, :version, km: 0, heap: nil, work: 0, expanded: 0]

  @typedoc """
  A D* Lite search: the `grid` as it is now, the robot's cell `start`, the
  `goal`, and `expanded`, the number of vertices the last `plan/1`
  processed (made consistent). Other fields are internal.
  """
  @type t :: %__MODULE__{
          grid: Grid.t(),
          start: Grid.cell(),
          goal: Grid.cell(),
          store: :atomics.atomics_ref(),
          version: pos_integer(),
          km: non_neg_integer(),
          heap: PairingHeap.t(),
          work: non_neg_integer(),
          expanded: non_neg_integer()
        }

  @doc """
  A search from `start` to `goal` on `grid` (both cells inside the grid;
  either may be blocked, `plan/1` then finds no path). Nothing is searched
  until `plan/1`.
  """
  @spec new(Grid.t(), Grid.cell(), Grid.cell()) :: t()
  def new(%Grid{width: w, height: h} = grid, start, goal) do
    inside!(grid, start)
    inside!(grid, goal)
    n = w * h
    a = :atomics.new(3 * n + 1, signed: true)
    {gc, gr} = goal
    gi = gr * w + gc
    # g stays infinite, rhs(goal) = 0: the goal is the one inconsistent vertex
    put_rhs(a, gi, 0)
    {sc, sr} = start
    k1 = Cost.octile(sc, sr, gc, gr)
    put_key(a, gi, k1)
    :atomics.put(a, 3 * n + 1, 1)

    %__MODULE__{
      grid: grid,
      start: start,
      goal: goal,
      store: a,
      version: 1,
      heap: PairingHeap.insert(nil, k1, 0, gi)
    }
  end

  @doc """
  Computes (or repairs) the shortest path from the current start to the
  goal: `{:ok, path, state}` with the path's cells from start to goal, or
  `{:error, :no_path, state}` (also when the start or the goal is blocked).
  The path's cost is `ThinkingCap.Navigation.AStar.cost/1` of it; the
  state's `expanded` counts the vertices this call processed.
  """
  @spec plan(t()) :: {:ok, [Grid.cell()], t()} | {:error, :no_path, t()}
  def plan(%__MODULE__{} = state) do
    state = next_version(state)
    %{grid: %Grid{width: w, height: h, cells: cells} = grid, store: a} = state
    {sc, sr} = state.start
    {gc, gr} = state.goal
    si = sr * w + sc
    gi = gr * w + gc
    ctx = {cells, w, h, a, sc, sr, state.km, gi}

    if Grid.passable?(grid, state.start) and Grid.passable?(grid, state.goal) do
      {heap, processed} = compute(ctx, si, state.heap, 0, g(a, si), rhs(a, si))
      work = state.work + processed
      state = maybe_compact(%{state | heap: heap, work: work, expanded: processed})

      with true <- rhs(a, si) < @inf,
           {:ok, path} <- walk(ctx, si, gi, w * h, [state.start]) do
        {:ok, path, state}
      else
        _ -> {:error, :no_path, state}
      end
    else
      {:error, :no_path, %{state | expanded: 0}}
    end
  end

  @doc """
  Cells change: each `{cell, blocked?}` blocks (`true`) or frees (`false`)
  a cell (cells outside the grid and cells that already are so are
  ignored). The vertices whose outgoing edges changed (the cells and their
  8 neighbours) get their rhs-values recomputed and are queued if that
  made them inconsistent; the next `plan/1` repairs the path from there.
  """
  @spec update_cells(t(), [{Grid.cell(), boolean()}]) :: t()
  def update_cells(%__MODULE__{} = state, changes) do
    state = next_version(state)
    %{grid: grid, store: a} = state

    changed =
      for {cell, blocked?} <- changes,
          Grid.inside?(grid, cell),
          Grid.passable?(grid, cell) == blocked?,
          into: %{},
          do: {cell, blocked?}

    if changed == %{} do
      state
    else
      %Grid{width: w, height: h, cells: cells} = grid = Grid.update(grid, Map.to_list(changed))
      {sc, sr} = state.start
      {gc, gr} = state.goal
      gi = gr * w + gc
      ctx = {cells, w, h, a, sc, sr, state.km, gi}

      affected =
        for {{col, row}, _} <- changed,
            dc <- -1..1,
            dr <- -1..1,
            c = col + dc,
            r = row + dr,
            c >= 0 and r >= 0 and c < w and r < h,
            uniq: true,
            do: r * w + c

      heap =
        Enum.reduce(affected, state.heap, fn
          ^gi, heap ->
            heap

          u, heap ->
            rhs = best_rhs(ctx, u)

            if rhs != rhs(a, u) do
              put_rhs(a, u, rhs)
              update_vertex(ctx, u, g(a, u), rhs, heap)
            else
              heap
            end
        end)

      %{state | grid: grid, heap: heap, work: state.work + length(affected)}
    end
  end

  @doc """
  The robot is now at `start` (a cell inside the grid, usually the next
  cells of the last path): the key modifier grows by the heuristic
  distance between the old and the new start, which keeps every queued key
  a lower bound of its new value.
  """
  @spec move_start(t(), Grid.cell()) :: t()
  def move_start(%__MODULE__{} = state, start) do
    state = next_version(state)
    inside!(state.grid, start)
    {oc, orow} = state.start
    {nc, nr} = start
    %{state | start: start, km: state.km + Cost.octile(oc, orow, nc, nr)}
  end

  ## ComputeShortestPath

  # ctx: {cells, width, height, store, start col, start row, km, goal index}
  # gs, rs: the start's g and rhs, read again whenever a vertex next to
  # the start (whose processing may change them) was processed
  defp compute({_, w, _, a, sc, sr, km, _} = ctx, si, heap, processed, gs, rs) do
    case pop_live(heap, a) do
      :empty ->
        {nil, processed}

      {k1, k2, u, rest, gu, ru} ->
        ms = min(gs, rs)

        if k1 < ms + km or (k1 == ms + km and k2 < ms) or rs > gs do
          col = rem(u, w)
          row = div(u, w)
          # the key's second part, min(g, rhs), is k2 for a live entry
          n1 = k2 + octile(sc, sr, col, row) + km

          cond do
            k1 < n1 ->
              put_key(a, u, n1)
              compute(ctx, si, insert(rest, n1, k2, u), processed, gs, rs)

            gu > ru ->
              # overconsistent: settle it, and offer the new g to its predecessors
              put_g(a, u, ru)
              remove(a, u)
              heap = lower(ctx, edges(ctx, u), ru, rest)
              computed(ctx, si, heap, processed + 1, gs, rs, col, row)

            true ->
              # underconsistent: forget its g; predecessors that relied on it look again
              put_g(a, u, @inf)
              heap = raise_preds(ctx, edges(ctx, u), gu, rest)
              heap = update_vertex(ctx, u, @inf, ru, heap)
              computed(ctx, si, heap, processed + 1, gs, rs, col, row)
          end
        else
          {insert(rest, k1, k2, u), processed}
        end
    end
  end

  defp computed({_, _, _, a, sc, sr, _, _} = ctx, si, heap, processed, gs, rs, col, row) do
    if abs(col - sc) <= 1 and abs(row - sr) <= 1,
      do: compute(ctx, si, heap, processed, g(a, si), rhs(a, si)),
      else: compute(ctx, si, heap, processed, gs, rs)
  end

  defp octile(c1, r1, c2, r2) do
    dx = abs(c1 - c2)
    dy = abs(r1 - r2)
    if dx > dy, do: @s * (dx - dy) + @d * dy, else: @s * (dy - dx) + @d * dx
  end

  defp lower(_ctx, [], _gu, heap), do: heap

  defp lower({_, _, _, _, _, _, _, gi} = ctx, [{gi, _} | rest], gu, heap),
    do: lower(ctx, rest, gu, heap)

  defp lower({_, _, _, a, _, _, _, _} = ctx, [{s, c} | rest], gu, heap) do
    v = c + gu

    if v < rhs(a, s) do
      put_rhs(a, s, v)
      lower(ctx, rest, gu, update_vertex(ctx, s, g(a, s), v, heap))
    else
      lower(ctx, rest, gu, heap)
    end
  end

  defp raise_preds(_ctx, [], _g_old, heap), do: heap

  defp raise_preds({_, _, _, _, _, _, _, gi} = ctx, [{gi, _} | rest], g_old, heap),
    do: raise_preds(ctx, rest, g_old, heap)

  defp raise_preds({_, _, _, a, _, _, _, _} = ctx, [{s, c} | rest], g_old, heap) do
    if rhs(a, s) == c + g_old do
      v = best_rhs(ctx, s)
      put_rhs(a, s, v)
      raise_preds(ctx, rest, g_old, update_vertex(ctx, s, g(a, s), v, heap))
    else
      raise_preds(ctx, rest, g_old, heap)
    end
  end

  # u's g and rhs just changed to these
  defp update_vertex({_, w, _, a, sc, sr, km, _}, u, g, rhs, heap) do
    if g != rhs do
      k2 = min(g, rhs)
      k1 = k2 + octile(sc, sr, rem(u, w), div(u, w)) + km
      put_key(a, u, k1)
      insert(heap, k1, k2, u)
    else
      remove(a, u)
      heap
    end
  end

  defp best([], _a, best, next), do: {best, next}

  defp best([{s, c} | rest], a, best, next) do
    v = c + g(a, s)
    if v < best, do: best(rest, a, v, s), else: best(rest, a, best, next)
  end

  # the top live entry of the queue, stale entries dropped on the way
  defp pop_live(heap, a) do
    case pop(heap) do
      :empty ->
        :empty

      {k1, k2, u, rest} ->
        with true <- :atomics.get(a, 3 * u + 3) == k1 + 1,
             gu = g(a, u),
             ru = rhs(a, u),
             true <- min(gu, ru) == k2 do
          {k1, k2, u, rest, gu, ru}
        else
          _ -> pop_live(rest, a)
        end
    end
  end

  # the path: from the start, always to the successor minimising c + g
  defp walk(_ctx, gi, gi, _left, path), do: {:ok, Enum.reverse(path)}
  defp walk(_ctx, _u, _gi, 0, _path), do: :no_path

  defp walk({_, w, _, a, _, _, _, _} = ctx, u, gi, left, path) do
    case best(edges(ctx, u), a, @inf, nil) do
      {best, _} when best >= @inf -> :no_path
      {_, next} -> walk(ctx, next, gi, left - 1, [{rem(next, w), div(next, w)} | path])
    end
  end

  ## The grid's edges: {neighbour index, cost}, none from a blocked cell

  defp edges({cells, w, h, _, _, _, _, _}, i) do
    {c, l, r, d, u, dl, dr, ul, ur} = around(cells, w, h, i)
    edges(i, w, c, l, r, d, u, dl, dr, ul, ur)
  end

  # the cell values of i and its neighbours (outside the grid: blocked)
  defp around(cells, w, h, i) do
    col = rem(i, w)
    row = div(i, w)

    if col > 0 and row > 0 and col < w - 1 and row < h - 1 do
      skip = w - 3

      <<_::binary-size(i - w - 1), dl, d, dr, _::binary-size(skip), l, c, r, _::binary-size(skip),
        ul, u, ur, _::binary>> = cells

      {c, l, r, d, u, dl, dr, ul, ur}
    else
      at = fn dc, dr ->
        {cc, rr} = {col + dc, row + dr}
        if cc >= 0 and rr >= 0 and cc < w and rr < h, do: :binary.at(cells, rr * w + cc), else: 1
      end

      {at.(0, 0), at.(-1, 0), at.(1, 0), at.(0, -1), at.(0, 1), at.(-1, -1), at.(1, -1),
       at.(-1, 1), at.(1, 1)}
    end
  end

  # rhs(i) = min over successors s of c(i, s) + g(s)
  defp best_rhs({cells, w, h, a, _, _, _, _}, i) do
    case around(cells, w, h, i) do
      {0, l, r, d, u, dl, dr, ul, ur} ->
        b = @inf
        b = if l == 0, do: min(b, @s + g(a, i - 1)), else: b
        b = if r == 0, do: min(b, @s + g(a, i + 1)), else: b
        b = if d == 0, do: min(b, @s + g(a, i - w)), else: b
        b = if u == 0, do: min(b, @s + g(a, i + w)), else: b
        b = if (l ||| d ||| dl) == 0, do: min(b, @d + g(a, i - w - 1)), else: b
        b = if (r ||| d ||| dr) == 0, do: min(b, @d + g(a, i - w + 1)), else: b
        b = if (l ||| u ||| ul) == 0, do: min(b, @d + g(a, i + w - 1)), else: b
        if (r ||| u ||| ur) == 0, do: min(b, @d + g(a, i + w + 1)), else: b

      _blocked ->
        @inf
    end
  end

  defp edges(_i, _w, c, _l, _r, _d, _u, _dl, _dr, _ul, _ur) when c != 0, do: []

  defp edges(i, w, _c, l, r, d, u, dl, dr, ul, ur) do
    acc = if (r ||| u ||| ur) == 0, do: [{i + w + 1, @d}], else: []
    acc = if (l ||| u ||| ul) == 0, do: [{i + w - 1, @d} | acc], else: acc
    acc = if (r ||| d ||| dr) == 0, do: [{i - w + 1, @d} | acc], else: acc
    acc = if (l ||| d ||| dl) == 0, do: [{i - w - 1, @d} | acc], else: acc
    acc = if u == 0, do: [{i + w, @s} | acc], else: acc
    acc = if d == 0, do: [{i - w, @s} | acc], else: acc
    acc = if r == 0, do: [{i + 1, @s} | acc], else: acc
    if l == 0, do: [{i - 1, @s} | acc], else: acc
  end

  ## The store: per cell g, rhs (as ∞ - value, so that 0 is ∞), key

  defp put_g(a, i, v), do: :atomics.put(a, 3 * i + 1, @inf - v)
  defp put_rhs(a, i, v), do: :atomics.put(a, 3 * i + 2, @inf - v)

  # a queued cell's key is {k1, min(g, rhs)}: only k1 is kept (0: not queued)
  defp put_key(a, i, k1), do: :atomics.put(a, 3 * i + 3, k1 + 1)
  defp remove(a, i), do: :atomics.put(a, 3 * i + 3, 0)

  defp next_version(%__MODULE__{store: a, version: v, grid: %Grid{width: w, height: h}} = state) do
    case :atomics.compare_exchange(a, 3 * w * h + 1, v, v + 1) do
      :ok ->
        %{state | version: v + 1}

      _ ->
        raise ArgumentError,
              "stale D* Lite state: pass the state returned by the last call on this search"
    end
  end

  defp inside!(grid, cell) do
    unless Grid.inside?(grid, cell),
      do:
        raise(
          ArgumentError,
          "cell #{inspect(cell)} outside the #{grid.width}×#{grid.height} grid"
        )
  end

  # rebuilds the queue from its live entries once the work since the last
  # rebuild outgrows the grid (stale entries pile up in between)
  defp maybe_compact(%__MODULE__{work: work, grid: %Grid{width: w, height: h}} = state) do
    if work < max(4096, div(w * h, 4)),
      do: state,
      else: %{state | heap: compact([state.heap], state.store, nil), work: 0}
  end

  defp compact([], _a, acc), do: acc
  defp compact([nil | rest], a, acc), do: compact(rest, a, acc)

  defp compact([{k1, k2, u, children} | rest], a, acc) do
    live = :atomics.get(a, 3 * u + 3) == k1 + 1 and min(g(a, u), rhs(a, u)) == k2
    acc = if live, do: insert(acc, k1, k2, u), else: acc
    compact(children ++ rest, a, acc)
  end

  # the pairing heap of Core.PairingHeap, inlined
  defp insert(nil, a, b, value), do: {a, b, value, []}

  defp insert({ha, hb, hv, hc} = heap, a, b, value) do
    if a < ha or (a == ha and b < hb),
      do: {a, b, value, [heap]},
      else: {ha, hb, hv, [{a, b, value, []} | hc]}
  end

  defp pop(nil), do: :empty
  defp pop({a, b, value, children}), do: {a, b, value, merge_pairs(children)}

  defp merge_pairs([]), do: nil
  defp merge_pairs([h]), do: h
  defp merge_pairs([h1, h2 | rest]), do: meld(meld(h1, h2), merge_pairs(rest))

  defp meld(h, nil), do: h

  defp meld({a1, b1, v1, c1} = h1, {a2, b2, v2, c2} = h2) do
    if a1 < a2 or (a1 == a2 and b1 <= b2),
      do: {a1, b1, v1, [h2 | c1]},
      else: {a2, b2, v2, [h1 | c2]}
  end
end
