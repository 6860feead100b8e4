defmodule ThinkingCap.Navigation.AStar do
  @moduledoc """
  Optimal path planning on a `ThinkingCap.Navigation.Grid` with A*.

  Moves are 8-connected: a straight step costs 1, a diagonal step √2, and
  a diagonal step is allowed only when both orthogonal cells it passes
  between are passable (no corner cutting). The heuristic is the octile
  distance, which is consistent for these moves, so the path found is
  optimal. Costs are in cells; `path_length_m/2` turns a path into metres.

  The search runs in exact integer arithmetic (see `cost/1`'s note). It
  runs in a short-lived process of its own, whose process dictionary is its
  scratch memory (the fastest mutable store on the BEAM): the g-score and
  closed mark of cell `{col, row}` under key `row * width + col`, and the
  open list as a bucket queue on exact f-scores (the buckets also in the
  dictionary, their f-scores in a pairing heap), last in first out within
  a bucket, which favours the deepest cells among equal f-scores. The
  path is read back from the goal along optimal predecessors; nothing is
  left behind in the caller.

      {:ok, %{path: path, cost: cost, expanded: n}} = AStar.plan(grid, {1, 1}, {40, 12})
  """

  import Bitwise, only: [|||: 2, <<<: 2]

  alias ThinkingCap.Navigation.Grid
  alias ThinkingCap.Navigation.Core.Cost

  require Cost

  @s Cost.straight()
  @d Cost.diagonal()

  @type cell :: Grid.cell()
  @type result :: %{path: [cell()], cost: float(), expanded: non_neg_integer()}
  @type error :: :no_path | :blocked_start | :blocked_goal

  @doc """
  The shortest path from `start` to `goal` (both cells, both included in
  `path`), its `cost` in cells and the number of cells `expanded` (closed)
  by the search.

  Errors: `:blocked_start` or `:blocked_goal` when that cell is outside the
  grid or blocked, `:no_path` when the goal cannot be reached. There are no
  options yet; `opts` is accepted for future ones.
  """
  @spec plan(Grid.t(), cell(), cell(), keyword()) :: {:ok, result()} | {:error, error()}
  def plan(%Grid{} = grid, start, goal, opts \\ []) when is_list(opts) do
    cond do
      not Grid.passable?(grid, start) -> {:error, :blocked_start}
      not Grid.passable?(grid, goal) -> {:error, :blocked_goal}
      true -> search(grid, start, goal)
    end
  end

  @doc """
  `plan/4` between two world points: each is mapped to its cell with
  `Grid.cell_of/2`, and the path comes back as the world positions of its
  cells' centres (`Grid.centre/2`). The result also holds `cells` (the
  path as cells) and `length_m` (`path_length_m/2`); `cost` stays in cells.
  """
  @spec plan_world(Grid.t(), {number(), number()}, {number(), number()}, keyword()) ::
          {:ok,
           %{
             path: [{float(), float()}],
             cells: [cell()],
             cost: float(),
             length_m: float(),
             expanded: non_neg_integer()
           }}
          | {:error, error()}
  def plan_world(%Grid{} = grid, from, to, opts \\ []) do
    with {:ok, %{path: cells} = result} <-
           plan(grid, Grid.cell_of(grid, from), Grid.cell_of(grid, to), opts) do
      {:ok,
       Map.merge(result, %{
         path: Enum.map(cells, &Grid.centre(grid, &1)),
         cells: cells,
         length_m: path_length_m(grid, cells)
       })}
    end
  end

  @doc """
  The length in metres of a path of cells: the sum of the distances between
  consecutive cell centres (1 or √2 cells for a step) times the grid's
  resolution.
  """
  @spec path_length_m(Grid.t(), [cell()]) :: float()
  def path_length_m(%Grid{resolution: r}, path), do: cost(path) * r

  @doc """
  The length in cells of a path of cells (the sum of the distances between
  consecutive cells; for the paths the planners return, straight steps
  count 1 and diagonal steps √2). The planners compare costs exactly in
  integer units of 2^-36 cell (√2 rounded to that grid), then report
  them with this function, so equal costs are equal floats.
  """
  @spec cost([cell()]) :: float()
  def cost([]), do: 0.0

  def cost([{_, _} | _] = path) do
    if adjacent_steps?(path),
      do: Cost.path_cost(path),
      else: path |> Enum.chunk_every(2, 1, :discard) |> Enum.map(&step/1) |> Enum.sum()
  end

  defp adjacent_steps?([_]), do: true

  defp adjacent_steps?([{c1, r1}, {c2, r2} = b | rest]),
    do: abs(c1 - c2) <= 1 and abs(r1 - r2) <= 1 and adjacent_steps?([b | rest])

  defp step([{c1, r1}, {c2, r2}]), do: :math.sqrt((c1 - c2) * (c1 - c2) + (r1 - r2) * (r1 - r2))

  ## The search

  defp search(%Grid{} = grid, start, goal) do
    if start == goal do
      {:ok, %{path: [start], cost: 0.0, expanded: 1}}
    else
      caller = self()
      ref = make_ref()

      search = fn -> send(caller, {ref, scratch_search(grid, start, goal)}) end

      {pid, monitor} =
        :erlang.spawn_opt(search, [
          :monitor,
          {:min_heap_size, min(grid.width * grid.height * 4, 1 <<< 22)}
        ])

      receive do
        {^ref, result} ->
          Process.demonitor(monitor, [:flush])
          result

        {:DOWN, ^monitor, :process, ^pid, reason} ->
          exit(reason)
      end
    end
  end

  defp scratch_search(%Grid{width: w, height: h, cells: cells}, {sc, sr}, {gc, gr} = goal) do
    si = sr * w + sc
    gi = gr * w + gc
    # cell value: :undefined unseen, g + 1 open, -(g + 1) closed
    :erlang.put(si, 1)
    f0 = Cost.octile(sc, sr, gc, gr)

    case loop([si], f0, nil, cells, w, h, gi, gc, gr, 0) do
      {:found, expanded} ->
        path = descend(cells, w, h, gc, gr, -:erlang.get(gi) - 1, [goal])
        {:ok, %{path: path, cost: Cost.path_cost(path), expanded: expanded}}

      :no_path ->
        {:error, :no_path}
    end
  end

  # The open list is a bucket queue on exact f-scores: `cur`, the cells of
  # the lowest f-score `f` (last in, first out: among equal f-scores the
  # deepest cells first), `buckets` the others by f-score and `fs` a
  # pairing heap of their f-scores. A cell whose g-score improves is pushed
  # again with a lower f-score, popped first; its older entries then find
  # it closed and are skipped. The heuristic is consistent, so f-scores
  # never decrease as cells are popped.
  defp loop([], _f, fs, cells, w, h, gi, gc, gr, expanded) do
    case fs do
      nil ->
        :no_path

      {f, children} ->
        cur = :erlang.erase(-f - 1)
        loop(cur, f, merge_pairs(children), cells, w, h, gi, gc, gr, expanded)
    end
  end

  defp loop([i | cur], f, fs, cells, w, h, gi, gc, gr, expanded) do
    v = :erlang.get(i)

    cond do
      v < 0 ->
        loop(cur, f, fs, cells, w, h, gi, gc, gr, expanded)

      i == gi ->
        :erlang.put(i, -v)
        {:found, expanded + 1}

      true ->
        :erlang.put(i, -v)
        {cur, fs} = expand({cur, fs}, f, i, v - 1, cells, w, h, gc, gr)
        loop(cur, f, fs, cells, w, h, gi, gc, gr, expanded + 1)
    end
  end

  defp expand(q, f0, i, g, cells, w, h, gc, gr) do
    col = rem(i, w)
    row = div(i, w)

    if col > 0 and row > 0 and col < w - 1 and row < h - 1 do
      # an inner cell: its 3×3 neighbourhood in one match
      skip = w - 3

      <<_::binary-size(i - w - 1), dl, d, dr, _::binary-size(skip), l, _, r, _::binary-size(skip),
        ul, u, ur, _::binary>> = cells

      neighbours(q, f0, i, g, w, gc, col, row, gr, l, r, d, u, dl, dr, ul, ur)
    else
      at = fn c, r ->
        if c >= 0 and r >= 0 and c < w and r < h, do: :binary.at(cells, r * w + c), else: 1
      end

      neighbours(
        q,
        f0,
        i,
        g,
        w,
        gc,
        col,
        row,
        gr,
        at.(col - 1, row),
        at.(col + 1, row),
        at.(col, row - 1),
        at.(col, row + 1),
        at.(col - 1, row - 1),
        at.(col + 1, row - 1),
        at.(col - 1, row + 1),
        at.(col + 1, row + 1)
      )
    end
  end

  # the cell values of the neighbours: left, right, down, up, then the diagonals
  defp neighbours(q, f0, i, g, w, gc, col, row, gr, l, r, d, u, dl, dr, ul, ur) do
    gs = g + @s
    gd = g + @d

    q = if l == 0, do: relax(q, f0, i - 1, col - 1, row, gs, gc, gr), else: q
    q = if r == 0, do: relax(q, f0, i + 1, col + 1, row, gs, gc, gr), else: q
    q = if d == 0, do: relax(q, f0, i - w, col, row - 1, gs, gc, gr), else: q
    q = if u == 0, do: relax(q, f0, i + w, col, row + 1, gs, gc, gr), else: q

    q =
      if (l ||| d ||| dl) == 0,
        do: relax(q, f0, i - w - 1, col - 1, row - 1, gd, gc, gr),
        else: q

    q =
      if (r ||| d ||| dr) == 0,
        do: relax(q, f0, i - w + 1, col + 1, row - 1, gd, gc, gr),
        else: q

    q =
      if (l ||| u ||| ul) == 0,
        do: relax(q, f0, i + w - 1, col - 1, row + 1, gd, gc, gr),
        else: q

    if (r ||| u ||| ur) == 0,
      do: relax(q, f0, i + w + 1, col + 1, row + 1, gd, gc, gr),
      else: q
  end

  defp relax({cur, fs} = q, f0, j, col, row, g, gc, gr) do
    v = :erlang.get(j)

    if g + 1 < v do
      :erlang.put(j, g + 1)
      dx = abs(col - gc)
      dy = abs(row - gr)
      f = if dx > dy, do: g + @s * (dx - dy) + @d * dy, else: g + @s * (dy - dx) + @d * dx

      if f == f0 do
        {[j | cur], fs}
      else
        # the bucket of f-score f is kept under key -f - 1
        case :erlang.put(-f - 1, [j]) do
          :undefined ->
            {cur, insert(fs, f)}

          list ->
            :erlang.put(-f - 1, [j | list])
            q
        end
      end
    else
      q
    end
  end

  # a pairing heap of f-scores: nil or {f, children}
  defp insert(nil, f), do: {f, []}
  defp insert({hf, _} = heap, f) when f < hf, do: {f, [heap]}
  defp insert({hf, hc}, f), do: {hf, [{f, []} | hc]}

  defp merge_pairs([]), do: nil
  defp merge_pairs([h]), do: h
  defp merge_pairs([h1, h2 | rest]), do: meld(meld(h1, h2), merge_pairs(rest))

  defp meld(h, nil), do: h
  defp meld({f1, c1}, {f2, _} = h2) when f1 <= f2, do: {f1, [h2 | c1]}
  defp meld(h1, {f2, c2}), do: {f2, [h1 | c2]}

  # Walks back from the goal along closed cells whose g-score plus the step
  # cost equals the current g-score: each is an optimal predecessor.
  defp descend(_cells, _w, _h, _col, _row, 0, path), do: path

  defp descend(cells, w, h, col, row, g, path) do
    {pc, pr, pg} = predecessor(cells, w, h, col, row, g)
    descend(cells, w, h, pc, pr, pg, [{pc, pr} | path])
  end

  @steps [{-1, 0}, {1, 0}, {0, -1}, {0, 1}, {-1, -1}, {1, -1}, {-1, 1}, {1, 1}]

  defp predecessor(cells, w, h, col, row, g) do
    Enum.find_value(@steps, fn {dc, dr} ->
      c = col + dc
      r = row + dr

      with true <- c >= 0 and r >= 0 and c < w and r < h,
           v when v < 0 <- :erlang.get(r * w + c),
           pg = -v - 1,
           true <- pg + step_cost(dc, dr) == g,
           true <- dc == 0 or dr == 0 or no_corner?(cells, w, col, row, c, r) do
        {c, r, pg}
      else
        _ -> nil
      end
    end)
  end

  defp step_cost(dc, dr) when dc == 0 or dr == 0, do: @s
  defp step_cost(_dc, _dr), do: @d

  defp no_corner?(cells, w, col, row, c, r),
    do: :binary.at(cells, row * w + c) == 0 and :binary.at(cells, r * w + col) == 0
end
