defmodule ThinkingCap.Navigation.Maps.PoseGraph do
  @moduledoc """
  Pose-graph SLAM's back end: the loop closure that keeps a map built
  from nothing true to itself when the robot comes back to where it was.

  The map builder adds a **node** every `node_distance` metres or
  `node_angle` radians the robot moves: its estimated pose, its odometry
  and its laser scan as points in the robot's frame. Each node is tied to
  the one before by an **edge**: where it lies seen from there (the
  localizer's step; the odometry's where the two disagree, a jump),
  with an information matrix that grows looser with the distance. The
  node is placed at the node before moved by that step; then, where its
  scan matches the scans of the `local_nodes` nodes before it, at their
  places in the graph and drawn as walls (`dense_points/3`), fixing the
  heading sharply (searched within 0.3 m and 0.06 rad, or 0.2
  rad when the best heading lies on that border), the node goes where the match
  puts it and the edge says so, with the match's spread: the whole pose
  where the match fixes the place too, the heading and the place across
  a corridor (the step along it), or else the heading alone. The edge's
  `via` says which (`:match`, `:corridor`, `:heading`; `:estimate` when
  the step was kept). The chain of nodes is then a
  scan matcher's against a submap of the last few metres: on generated
  buildings it drifts 0.06–0.10 m and 0.012–0.022 rad over 10 m, the
  localizer against the map it draws 0.09–0.16 m and 0.018–0.025 rad.
  `estimate/2` keeps the localizer's estimate of each node, the frame
  the map builder's scans are kept in.

  Then the new node's scan is matched (`ThinkingCap.Navigation.Core.GridNif`'s
  correlative `slam_match`) against the scans of the old nodes near it:
  the nearest node at least `loop_gap` nodes back within `loop_radius`
  metres, and its neighbours in the chain. A
  match that scores at least `min_score` (the mean likelihood of its
  points), lies inside the search window (not on its border), fits
  clearly better than the estimate when it moves it far (more than
  0.15 m or 0.05 rad: by 5 % of the points), and fixes the pose sharply (σ at most `max_sigma` m and
  `max_sigma_angle` rad) is a **loop closure**: an edge from the old node.
  A large correction (more than 0.15 m or 0.05 rad) must be said by two
  nodes' matches alike (this one's and one of the two before): one scan
  may fit a wrong place well by chance, two in a row seldom do.
  In a corridor a scan fixes the place across it and the heading, not
  the place along it: the match's scores run level along the corridor
  through the window. Such a match moves the pose only across the
  corridor, by at most 0.15 m (farther, one wall may have been taken for
  another beside it), and its edge holds the pose across it and hardly
  along it (σ 1 m). The graph
  is then optimized (Gauss-Newton, `slam_optimize`), and a loop edge that
  does not fit the rest afterwards (χ² above `max_chi2`) is dropped and
  the graph optimized again.

  With `loop_heading_scale` above 1, a loop edge's heading is trusted
  that many times less than its match's spread says: the loop edges that
  share an old node share its submap and its errors. On generated
  building 5 their headings erred 1.4 to 2 times the spread they
  claimed, and its final graph, optimized again offline with their
  heading variance ten times larger, came 0.58 m off the truth instead
  of 0.71. Explorations with 3 were better in three runs of four on
  buildings 5 and 21 and worse in one (README, the explore rows): the
  default stays 1.

  All poses are `{x, y, θ}` in the map's frame. Node ids count from 0;
  node 0 is held where it is.
  """

  alias ThinkingCap.Navigation.Core.GridNif
  alias ThinkingCap.Navigation.EKF
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  # the variance given to a corridor's match along the corridor, m²
  @along_variance 1.0
  # the farthest a corridor's match moves the pose across it, m: across a
  # corridor the localizer seldom errs by more; a match that says so has
  # more likely taken one wall for another beside it
  @ridge_move 0.15

  defstruct pending: nil,
            nodes: %{},
            estimates: %{},
            odometry: %{},
            points: %{},
            along: %{},
            edges: [],
            next: 0,
            params: %{}

  @type pose :: {float(), float(), float()}
  @type edge :: %{
          optional(:via) => :match | :corridor | :heading | :estimate,
          required(:from) => non_neg_integer(),
          required(:to) => non_neg_integer(),
          required(:z) => pose(),
          required(:info) => {float(), float(), float(), float(), float(), float()},
          required(:kind) => :sequence | :odometry | :loop
        }
  @type t :: %__MODULE__{
          pending: {non_neg_integer(), pose()} | nil,
          nodes: %{non_neg_integer() => pose()},
          estimates: %{non_neg_integer() => pose()},
          odometry: %{non_neg_integer() => pose() | nil},
          points: %{non_neg_integer() => binary()},
          along: %{non_neg_integer() => float()},
          edges: [edge()],
          next: non_neg_integer(),
          params: map()
        }

  @defaults %{
    node_distance: 0.3,
    node_angle: 0.35,
    loop_gap: 30,
    loop_radius: 4.0,
    window: 0.5,
    window_angle: 0.2,
    window_growth: 0.01,
    window_angle_growth: 0.002,
    max_window: 1.2,
    max_window_angle: 0.35,
    min_score: 0.45,
    max_sigma: 0.08,
    max_sigma_angle: 0.03,
    max_chi2: 16.0,
    resolution: 0.05,
    submap_nodes: 5,
    local_nodes: 10,
    loop_heading_scale: 1.0,
    wall_gap: 0.3,
    local_sigma: 0.05,
    local_sigma_angle: 0.03
  }

  # the window of the match of a node against the nodes before it: the
  # localizer's estimate is seldom further off from them
  @local_window {0.3, 0.06}
  # and where the best lies on that window's border: in a fast turn the
  # estimate's heading may be a tenth of a radian off
  @local_wide_window {0.3, 0.2}

  @doc """
  An empty graph. Options (defaults in brackets): `node_distance` [0.3],
  `node_angle` [0.35], `loop_gap` [30], `loop_radius` [4.0], `window`
  [0.5 m] and `window_angle` [0.2 rad] (how far from the estimate a loop
  match is sought, at least), `window_growth` [0.01 m per m] and
  `window_angle_growth` [0.002 rad per m] (how much wider the window is
  for every metre the robot drove from the old node to the new one: the
  drift a long way round gathers), `max_window` [1.2 m],
  `max_window_angle` [0.35 rad], `min_score` [0.45], `max_sigma` [0.08],
  `max_sigma_angle` [0.03], `max_chi2` [16], `resolution` [0.05],
  `submap_nodes` [5] (the old nodes matched against: those within this
  many of the nearest; a short stretch of the chain is true to itself,
  a long one is not), `local_nodes` [10] (how many nodes before a new
  one its scan is matched against for the edge from the node before; 0:
  the estimate alone makes the edge), `local_sigma_angle` [0.03 rad]
  (how sharply that match must fix the heading for the edge; else the
  estimate makes it: the estimate's heading follows the odometry's turn
  errors, so a chain left to it where matches are a little less sharp
  turns the whole map; with 0.01 rad a third of the nodes on generated
  building 1 were left to it and the graph turned 0.07 rad in 150 s),
  `local_sigma` [0.05 m] (how sharply it must fix the place too, or
  across a corridor, for the edge to take the place from it; else the
  edge takes the heading alone), `loop_heading_scale` [1.0] (how
  many times its match's standard deviation a loop edge's heading is
  given).
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []), do: %__MODULE__{params: Map.merge(@defaults, Map.new(opts))}

  @doc "The number of nodes."
  @spec size(t()) :: non_neg_integer()
  def size(%__MODULE__{next: n}), do: n

  @doc "The latest node's id, or nil."
  @spec last(t()) :: non_neg_integer() | nil
  def last(%__MODULE__{next: 0}), do: nil
  def last(%__MODULE__{next: n}), do: n - 1

  @doc "A node's pose."
  @spec pose(t(), non_neg_integer()) :: pose()
  def pose(%__MODULE__{nodes: nodes}, id), do: Map.fetch!(nodes, id)

  @doc """
  Whether the robot at `pose` is far enough from the latest node for a
  new one.
  """
  @spec due?(t(), pose()) :: boolean()
  def due?(%__MODULE__{next: 0}, _pose), do: true

  def due?(%__MODULE__{params: p} = g, {x, y, th}) do
    {lx, ly, lth} = estimate(g, last(g))

    :math.sqrt((x - lx) ** 2 + (y - ly) ** 2) >= p.node_distance or
      abs(normalize_angle(th - lth)) >= p.node_angle
  end

  @doc """
  The localizer's estimate a node was added at (`add_node/4`), carried
  into the current frame by `follow/3`: the frame the scans kept with the
  node are placed in.
  """
  @spec estimate(t(), non_neg_integer()) :: pose()
  def estimate(%__MODULE__{estimates: e}, id), do: Map.fetch!(e, id)

  @doc """
  Sets the estimate of node `id` (`estimate/1`): the localizer's estimate
  was carried to `pose` (a closed loop moved the map's frame).
  """
  @spec follow(t(), non_neg_integer(), pose()) :: t()
  def follow(%__MODULE__{} = g, id, pose), do: %{g | estimates: Map.put(g.estimates, id, pose)}

  @doc """
  Adds a node for the localizer's estimate `pose` with the `odometry`
  reading of the same instant (or nil) and its scan `points` (native
  doubles `{x, y}` in the robot's frame), tied to the node before.

  The node is placed where the node before lies in the graph, moved by
  the estimate's step since (the odometry's where the two disagree, a
  jump); then its scan is matched against the scans of the `local_nodes`
  nodes before it at their places in the graph, and where the match is
  sharp, the node goes where it says: the chain of nodes is a scan
  matcher's against a submap of the last few metres, which drifts less
  than the localizer against the map it draws. `estimate/2` keeps the
  localizer's estimate. Returns the new node's id and the graph.
  """
  @spec add_node(t(), pose(), pose() | nil, binary()) :: {non_neg_integer(), t()}
  def add_node(%__MODULE__{next: id} = g, pose, odometry, points) when is_binary(points) do
    along =
      case id do
        0 -> 0.0
        _ -> g.along[id - 1] + distance(estimate(g, id - 1), pose)
      end

    g = %{
      g
      | estimates: Map.put(g.estimates, id, pose),
        along: Map.put(g.along, id, along),
        odometry: Map.put(g.odometry, id, odometry),
        points: Map.put(g.points, id, points),
        next: id + 1
    }

    case id do
      0 ->
        {id, %{g | nodes: Map.put(g.nodes, id, pose)}}

      _ ->
        e = sequence_edge(g, id - 1, id)
        at = EKF.motion(pose(g, id - 1), e.z)
        {id, %{g | nodes: Map.put(g.nodes, id, at), edges: [e | g.edges]}}
    end
  end

  # the estimate's step, unless it jumped away from the odometry's; then
  # the node's scan against the nodes' before
  defp sequence_edge(g, i, j) do
    z = EKF.relative(estimate(g, i), estimate(g, j))
    {zx, zy, zth} = z
    d = :math.sqrt(zx * zx + zy * zy)

    case odometry_step(g, i, j) do
      {_, _, oth} = o ->
        if jumped?(z, o, d),
          do: edge(i, j, o, 0.03 + 0.1 * d, 0.02 + 0.1 * abs(oth) + 0.05 * d, :odometry),
          else: edge(i, j, z, 0.01 + 0.03 * d, 0.005 + 0.03 * abs(zth) + 0.01 * d, :sequence)

      nil ->
        edge(i, j, z, 0.01 + 0.03 * d, 0.005 + 0.03 * abs(zth) + 0.01 * d, :sequence)
    end
    |> local_match(g)
  end

  # the node's scan against the scans of the nodes before it, at their
  # places in the graph, drawn as walls (`dense_points/3`). A match that
  # fixes the heading sharply makes the edge from the node before, with
  # the match's spread (and a floor) as its uncertainty: all of it where
  # it fixes the place too; in a corridor, the heading and the place
  # across it, the estimate's step along it; elsewhere the heading alone.
  # The estimate's heading follows the odometry's turn errors, and what
  # is left to it turns the chain. A match found on its window's border
  # (the estimate more than 0.06 rad off, as in a fast turn) is sought
  # again in a wider window.
  defp local_match(%{kind: :sequence, from: i, to: j, z: z} = e, %{params: %{local_nodes: k}} = g)
       when k > 0 do
    query = Map.fetch!(g.points, j)
    fill = g.params.resolution / 2

    ref =
      IO.iodata_to_binary(
        for n <- max(0, j - k)..i//1,
            do: dense_points(world_points(g, n), fill, g.params.wall_gap)
      )

    guess = EKF.motion(pose(g, i), z)

    with true <- byte_size(query) >= 16 * 20 and byte_size(ref) >= 16 * 20,
         {matched, score, cov, _at_guess, ridge} when score >= g.params.min_score <-
           local_search(ref, query, guess, g.params.resolution),
         {:ok, at, cov, via} <- local_fix(g.params, guess, matched, cov, ridge, e),
         {:ok, local} <- loop_edge(g, i, j, at, cov, 1.0) do
      Map.merge(local, %{kind: :sequence, via: via})
    else
      _ -> Map.put(e, :via, :estimate)
    end
  end

  defp local_match(e, _g), do: e

  defp local_search(ref, query, guess, res) do
    with :none <- GridNif.slam_match(ref, query, guess, @local_window, res, res),
         do: GridNif.slam_match(ref, query, guess, @local_wide_window, res, res)
  end

  # what of the match the edge takes: all of it, the heading and the
  # place across a corridor, or the heading alone; the rest from the
  # estimate's step (`e`, whose spread it keeps)
  defp local_fix(p, {gx, gy, _} = guess, {_, _, mth} = matched, cov, ridge, e) do
    {cxx, cxy, _cxt, cyy, _cyt, ctt} = cov
    {big, small, {ex, ey}} = principal(cxx, cxy, cyy)
    {a, _, _, _, _, _} = e.info
    step_variance = 1.0 / a

    cond do
      :math.sqrt(ctt) > p.local_sigma_angle ->
        :none

      :math.sqrt(big) <= p.local_sigma ->
        {:ok, matched, cov, :match}

      ridge and :math.sqrt(small) <= p.local_sigma ->
        with {:ok, moved, cov} <-
               ridge_match(guess, matched, small, {ex, ey}, cov, step_variance),
             do: {:ok, moved, cov, :corridor}

      true ->
        {:ok, {gx, gy, mth}, {step_variance, 0.0, 0.0, step_variance, 0.0, ctt}, :heading}
    end
  end

  defp odometry_step(g, i, j) do
    case {g.odometry[i], g.odometry[j]} do
      {a, b} when is_tuple(a) and is_tuple(b) -> EKF.relative(a, b)
      _ -> nil
    end
  end

  defp jumped?({zx, zy, zth}, {ox, oy, oth}, d) do
    :math.sqrt((zx - ox) ** 2 + (zy - oy) ** 2) > 0.1 + 0.1 * d or
      abs(normalize_angle(zth - oth)) > 0.05 + 0.1 * abs(oth)
  end

  defp edge(i, j, z, s_xy, s_th, kind) do
    a = 1.0 / (s_xy * s_xy)
    %{from: i, to: j, z: z, info: {a, 0.0, 0.0, a, 0.0, 1.0 / (s_th * s_th)}, kind: kind}
  end

  @doc """
  Seeks a loop closure for node `id` (normally the latest): matches its
  scan against the old nodes near it, and when a match holds, adds the
  loop edge and optimizes the graph. Returns `{:closed, graph, from, to}`
  with the latest node's estimate before and its pose after (the
  estimate is moved there: the caller moves the localizer's), or
  `{:none, graph}`.
  """
  @spec close_loop(t(), non_neg_integer()) ::
          {:closed, t(), pose(), pose()} | {:none, t()}
  def close_loop(%__MODULE__{} = g, id) do
    with {:ok, anchor, ref} <- submap(g, id),
         {:ok, matched, cov} <- match(g, id, ref, window(g, anchor, id)),
         {:ok, g} <- confirmed(g, id, matched),
         {:ok, edge} <- loop_edge(g, anchor, id, matched, cov, g.params.loop_heading_scale) do
      if agrees?(g, edge) do
        # the graph already says so: kept, nothing to optimize
        {:none, %{g | edges: [edge | g.edges]}}
      else
        before = estimate(g, last(g))
        g = optimize(%{g | edges: [edge | g.edges]})

        # the caller moves its estimate from `before` to the node's pose
        if Enum.any?(g.edges, &(&1 == edge)),
          do: {:closed, follow(g, last(g), pose(g, last(g))), before, pose(g, last(g))},
          else: {:none, g}
      end
    else
      {:pending, g} -> {:none, g}
      _ -> {:none, g}
    end
  end

  # A large correction (more than 0.15 m or 0.05 rad) must be said twice:
  # by this node's match and by one of the two nodes' before, alike
  # within 0.1 m and 0.03 rad. One scan may fit a wrong place well by
  # chance (a row of doors, boxes like others); two in a row seldom do.
  defp confirmed(g, id, matched) do
    {x, y, th} = pose(g, id)
    {mx, my, mth} = matched
    c = {mx - x, my - y, normalize_angle(mth - th)}

    cond do
      not large?(c) ->
        {:ok, g}

      alike?(g.pending, id, c) ->
        {:ok, %{g | pending: nil}}

      true ->
        {:pending, %{g | pending: {id, c}}}
    end
  end

  defp large?({dx, dy, dth}), do: :math.sqrt(dx * dx + dy * dy) > 0.15 or abs(dth) > 0.05

  defp alike?({pid, {px, py, pth}}, id, {dx, dy, dth}) when id - pid <= 2,
    do: :math.sqrt((dx - px) ** 2 + (dy - py) ** 2) <= 0.1 and abs(dth - pth) <= 0.03

  defp alike?(_pending, _id, _c), do: false

  # whether a loop edge says what the graph's poses say already (within
  # 1 cm and 0.2 degrees)
  defp agrees?(g, %{from: i, to: j, z: {zx, zy, zth}}) do
    {x, y, th} = EKF.relative(pose(g, i), pose(g, j))
    :math.sqrt((x - zx) ** 2 + (y - zy) ** 2) < 0.01 and abs(normalize_angle(th - zth)) < 0.0035
  end

  # the old nodes near `id`: the nearest is the anchor; the submap is the
  # points of the nodes round it, in the map's frame
  defp submap(%__MODULE__{params: p} = g, id) do
    {x, y, _} = pose(g, id)

    near =
      for {j, {jx, jy, _}} <- g.nodes,
          j <= id - p.loop_gap,
          d = :math.sqrt((jx - x) ** 2 + (jy - y) ** 2),
          d <= p.loop_radius,
          do: {d, j}

    case near do
      [] ->
        :none

      _ ->
        {_, anchor} = Enum.min(near)
        around = for {_d, j} <- near, abs(j - anchor) <= p.submap_nodes, do: j
        ref = IO.iodata_to_binary(Enum.map(around, &world_points(g, &1)))
        {:ok, anchor, ref}
    end
  end

  defp world_points(g, j) do
    {x, y, th} = pose(g, j)
    {c, s} = {:math.cos(th), :math.sin(th)}

    for <<px::float-native, py::float-native <- Map.fetch!(g.points, j)>>,
      into: <<>>,
      do: <<x + c * px - s * py::float-native, y + s * px + c * py::float-native>>
  end

  @doc """
  A scan's points (native doubles `{x, y}`, in beam order) with the
  gaps between neighbours filled every `step` m where they lie at most
  `max_gap` m apart: the walls the scan saw as lines, not as beads.
  Matched against beads, a scan seen from elsewhere falls between them
  and is pulled along the wall; against lines it is not.
  """
  @spec dense_points(binary(), float(), float()) :: binary()
  def dense_points(points, step, max_gap)

  def dense_points(<<x::float-native, y::float-native, rest::binary>>, step, max_gap),
    do:
      IO.iodata_to_binary(
        dense(rest, x, y, step, max_gap, [<<x::float-native, y::float-native>>])
      )

  def dense_points(<<>>, _step, _max_gap), do: <<>>

  defp dense(<<bx::float-native, by::float-native, rest::binary>>, ax, ay, step, max_gap, acc) do
    d = :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
    n = if d <= max_gap, do: ceil(d / step), else: 1

    fill =
      for i <- 1..n//1,
          into: <<>>,
          do: <<ax + (bx - ax) * i / n::float-native, ay + (by - ay) * i / n::float-native>>

    dense(rest, bx, by, step, max_gap, [acc | fill])
  end

  defp dense(_rest, _ax, _ay, _step, _max_gap, acc), do: acc

  # the search window round the estimate: wider the longer the way the
  # robot drove from the old node (the drift it may have gathered)
  defp window(%__MODULE__{params: p} = g, anchor, id) do
    driven = g.along[id] - g.along[anchor]

    {min(max(p.window, p.window_growth * driven), p.max_window),
     min(max(p.window_angle, p.window_angle_growth * driven), p.max_window_angle)}
  end

  defp distance({ax, ay, _}, {bx, by, _}), do: :math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)

  defp match(%__MODULE__{params: p} = g, id, ref, window) do
    query = Map.fetch!(g.points, id)

    if byte_size(query) < 16 * 20 do
      :none
    else
      case GridNif.slam_match(
             ref,
             query,
             pose(g, id),
             window,
             p.resolution,
             p.resolution
           ) do
        {matched, score, cov, at_guess, ridge} when score >= p.min_score ->
          with {:ok, matched, cov} <- sharp(p, pose(g, id), matched, cov, ridge),
               true <- decisive?(pose(g, id), matched, score, at_guess) do
            {:ok, matched, cov}
          else
            _ -> :none
          end

        _ ->
          :none
      end
    end
  end

  # a large correction must fit clearly better than the estimate: where
  # the estimate fits nearly as well, the scan does not say it is wrong
  defp decisive?({x, y, th}, {mx, my, mth}, score, at_guess) do
    small =
      :math.sqrt((mx - x) ** 2 + (my - y) ** 2) <= 0.15 and abs(normalize_angle(mth - th)) <= 0.05

    small or score - at_guess >= 0.05
  end

  # A match must fix the heading and the place sharply. In a corridor (the
  # scores run level along it through the window: `ridge`) it fixes the
  # place across the corridor but not along it: then the match moves the
  # pose only across, and the edge says next to nothing along it.
  defp sharp(p, guess, matched, {cxx, cxy, _, cyy, _, ctt} = cov, ridge) do
    {big, small, {ex, ey}} = principal(cxx, cxy, cyy)

    cond do
      :math.sqrt(ctt) > p.max_sigma_angle or :math.sqrt(small) > p.max_sigma ->
        :none

      :math.sqrt(big) <= p.max_sigma ->
        {:ok, matched, cov}

      ridge ->
        ridge_match(guess, matched, small, {ex, ey}, cov, @along_variance)

      true ->
        :none
    end
  end

  # a corridor's match: the pose moved only across the corridor (at most
  # @ridge_move), kept along it as `guess` has it; its spread across
  # the match's, along it `l`
  defp ridge_match({gx, gy, _}, {mx, my, mth}, small, {ex, ey}, cov, l) do
    along = (mx - gx) * ex + (my - gy) * ey
    across = -(mx - gx) * ey + (my - gy) * ex

    if abs(across) <= @ridge_move,
      do: ridge_cov({mx - along * ex, my - along * ey, mth}, small, {ex, ey}, cov, l),
      else: :none
  end

  defp ridge_cov(moved, small, {ex, ey}, {_, _, cxt, _, cyt, ctt}, l) do
    {ax, ay} = {-ey, ex}
    at = cxt * ax + cyt * ay

    cov =
      {small * ax * ax + l * ex * ex, small * ax * ay + l * ex * ey, at * ax,
       small * ay * ay + l * ey * ey, at * ay, ctt}

    {:ok, moved, cov}
  end

  # the eigenvalues of a symmetric 2x2 (larger first) and the larger's
  # unit eigenvector
  defp principal(a, b, d) do
    half = (a + d) / 2
    disc = :math.sqrt(max(0.0, (a - d) * (a - d) / 4 + b * b))
    big = half + disc

    {ex, ey} =
      cond do
        abs(b) > 1.0e-12 -> {b, big - a}
        a >= d -> {1.0, 0.0}
        true -> {0.0, 1.0}
      end

    n = :math.sqrt(ex * ex + ey * ey)
    {big, half - disc, {ex / n, ey / n}}
  end

  defp loop_edge(g, anchor, id, matched, {cxx, cxy, cxt, cyy, cyt, ctt}, k) do
    # the match's covariance, in the anchor's frame, with a floor; the
    # heading's standard deviation times k (its cross terms with it)
    {_, _, th} = pose(g, anchor)
    {c, s} = {:math.cos(th), :math.sin(th)}
    # R^T C R for the position block
    rxx = c * c * cxx + 2 * c * s * cxy + s * s * cyy
    ryy = s * s * cxx - 2 * c * s * cxy + c * c * cyy
    rxy = (c * c - s * s) * cxy + c * s * (cyy - cxx)
    rxt = c * cxt + s * cyt
    ryt = -s * cxt + c * cyt
    cov = {rxx + 0.02 ** 2, rxy, k * rxt, ryy + 0.02 ** 2, k * ryt, k * k * (ctt + 0.005 ** 2)}

    case invert(cov) do
      nil ->
        :none

      info ->
        {:ok,
         %{
           from: anchor,
           to: id,
           z: EKF.relative(pose(g, anchor), matched),
           info: info,
           kind: :loop
         }}
    end
  end

  # the inverse of a symmetric 3x3 given by its upper half
  defp invert({a, b, c, d, e, f}) do
    det = a * (d * f - e * e) - b * (b * f - e * c) + c * (b * e - d * c)

    if abs(det) < 1.0e-18 do
      nil
    else
      {(d * f - e * e) / det, (c * e - b * f) / det, (b * e - c * d) / det, (a * f - c * c) / det,
       (b * c - a * e) / det, (a * d - b * b) / det}
    end
  end

  @doc """
  Optimizes every node's pose to fit the edges best; a loop edge whose χ²
  stays above `max_chi2` afterwards is dropped (the worst one at a time,
  at most three), and the graph optimized again.
  """
  @spec optimize(t(), non_neg_integer()) :: t()
  def optimize(%__MODULE__{} = g, rounds \\ 3) do
    edges = Enum.reverse(g.edges)
    nodes = for id <- 0..(g.next - 1)//1, into: <<>>, do: pose_bin(pose(g, id))

    edge_bin =
      for %{from: i, to: j, z: {zx, zy, zth}, info: {a, b, c, d, e, f}} <- edges, into: <<>> do
        for v <- [i, j, zx, zy, zth, a, b, c, d, e, f], into: <<>>, do: <<v * 1.0::float-native>>
      end

    {out, chis} = GridNif.slam_optimize(nodes, edge_bin, 10)
    chi2 = for <<v::float-native <- chis>>, do: v

    poses =
      for {<<x::float-native, y::float-native, th::float-native>>, id} <-
            Enum.with_index(chunks(out)),
          into: %{},
          do: {id, {x, y, th}}

    worst =
      edges
      |> Enum.zip(chi2)
      |> Enum.filter(fn {e, chi} -> e.kind == :loop and chi > g.params.max_chi2 end)
      |> Enum.max_by(fn {_e, chi} -> chi end, fn -> nil end)

    case worst do
      {bad, _chi} when rounds > 0 ->
        optimize(%{g | edges: List.delete(g.edges, bad)}, rounds - 1)

      _ ->
        %{g | nodes: poses}
    end
  end

  defp chunks(<<>>), do: []
  defp chunks(<<p::binary-size(24), rest::binary>>), do: [p | chunks(rest)]

  defp pose_bin({x, y, th}),
    do: <<x * 1.0::float-native, y * 1.0::float-native, th * 1.0::float-native>>

  @doc """
  A laser scan's endpoints as points in the robot's frame (native doubles
  `{x, y}`), for `add_node/4`: the sensor at `sensor` on the robot, every
  `step`-th beam that has an echo.
  """
  @spec scan_points(map(), pose(), pos_integer()) :: binary()
  def scan_points(scan, {sx, sy, sth}, step \\ 1) do
    range_min = Map.get(scan, :range_min, 0.0)

    scan.ranges
    |> Enum.with_index()
    |> Enum.filter(fn {r, i} ->
      rem(i, step) == 0 and is_number(r) and r >= range_min and r < scan.range_max
    end)
    |> Enum.map(fn {r, i} ->
      a = sth + scan.angle_min + i * scan.angle_increment
      <<sx + r * :math.cos(a)::float-native, sy + r * :math.sin(a)::float-native>>
    end)
    |> IO.iodata_to_binary()
  end
end
