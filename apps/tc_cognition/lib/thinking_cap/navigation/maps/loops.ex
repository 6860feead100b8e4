defmodule ThinkingCap.Navigation.Maps.Loops do
  @moduledoc """
  The map builder's loop closure, for a map built from nothing
  (`ThinkingCap.Navigation.Mapper`): it keeps the laser scans the map was
  drawn from and a pose graph (`ThinkingCap.Navigation.Maps.PoseGraph`)
  of where they were taken, closes loops when the robot comes back to
  where it was, and then draws the map again from the scans at their
  corrected poses.

  Every scan is kept (ranges as 32-bit floats) when the robot has moved
  `keep_distance` m or turned `keep_angle` rad since the last one kept,
  at its pose relative to its node of the graph: when the graph's poses
  move, the scans move with their nodes.

  A closed loop moves the map's frame under the robot: `frame/1` counts
  the moves, and `carry/3` brings a pose estimated in an older frame into
  the current one.
  """

  alias ThinkingCap.Navigation.EKF
  alias ThinkingCap.Navigation.Maps.{PoseGraph, SensedGrid}
  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  defstruct graph: nil,
            scans: [],
            count: 0,
            kept: nil,
            meta: %{},
            frame: 0,
            moves: %{},
            params: %{}

  @type pose :: {float(), float(), float()}
  @type t :: %__MODULE__{
          graph: PoseGraph.t(),
          scans: [{non_neg_integer(), pose(), atom(), binary()}],
          count: non_neg_integer(),
          kept: pose() | nil,
          meta: %{atom() => map()},
          frame: non_neg_integer(),
          moves: %{non_neg_integer() => {pose(), pose()}},
          params: map()
        }

  @defaults %{
    keep_distance: 0.05,
    keep_angle: 0.05,
    point_step: 2,
    loop_every: 1,
    redraw_distance: 0.03,
    redraw_angle: 0.01,
    follow_distance: 0.05,
    follow_angle: 0.015
  }

  @doc """
  Nothing kept yet. Options: `keep_distance` [0.05], `keep_angle`
  [0.05], `point_step` [2] (every how many beams a node's scan keeps a
  point for matching), `loop_every` [1] (every how many nodes a loop is
  sought), `redraw_distance` [0.03] and `redraw_angle` [0.01] (how far a
  closed loop must move some node for the map to be drawn again: a
  smaller correction stays in the graph until the next),
  `follow_distance` [0.05] and `follow_angle` [0.015] (how far the
  newest node of the graph's chain of scan matches may lie from the
  localizer's estimate of it before the map is drawn again at the
  graph's poses and the localizer moved onto it; 0: never), and the
  graph's (`PoseGraph.new/1`).
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    {own, graph} = Keyword.split(opts, Map.keys(@defaults))
    %__MODULE__{graph: PoseGraph.new(graph), params: Map.merge(@defaults, Map.new(own))}
  end

  @doc "The number of loop closures so far: the map's frame."
  @spec frame(t()) :: non_neg_integer()
  def frame(%__MODULE__{frame: f}), do: f

  @doc """
  Records a laser `scan` from the sensor `tag` (mounted at `mount` on the
  robot) taken at `pose`, with the `odometry` reading of its instant (or
  nil). Returns the loops and `:none`, or `{:closed, from, to}` when the
  scan closed a loop: the robot's pose `from` before is `to` now; the
  map must then be drawn again (`redraw/4`).
  """
  @spec record(t(), atom(), pose(), map(), pose(), pose() | nil) ::
          {t(), :none | {:closed, pose(), pose()}}
  def record(%__MODULE__{} = loops, tag, mount, scan, pose, odometry) do
    loops = %{loops | meta: Map.put_new_lazy(loops.meta, tag, fn -> meta(scan) end)}

    {loops, result} =
      if PoseGraph.due?(loops.graph, pose) do
        points = PoseGraph.scan_points(scan, mount, loops.params.point_step)
        {id, graph} = PoseGraph.add_node(loops.graph, pose, odometry, points)

        with true <- rem(id, loops.params.loop_every) == 0,
             {:closed, closed, from, to} <- PoseGraph.close_loop(graph, id) do
          if shifted?(graph, closed, loops.params) do
            move_frame(loops, closed, id, from, to)
          else
            # a correction too small to draw the map again for: the graph
            # keeps it, the map and the localizer catch up at the next
            {%{loops | graph: PoseGraph.follow(closed, id, from)}, :none}
          end
        else
          {:none, graph} -> follow(loops, graph, id)
          false -> follow(loops, graph, id)
        end
      else
        {loops, :none}
      end

    # the scan is kept at the pose it had when it was taken, carried into
    # the frame the graph is in now
    pose = carry_to(loops, pose, result)
    {keep(loops, tag, scan, pose), result}
  end

  # the map's frame moved: the localizer's estimate `from` of node `id`
  # is `to` now
  defp move_frame(loops, graph, id, from, to) do
    frame = loops.frame + 1
    # only the last move is carried (carry/3): older frames are too old
    moves = %{frame => {from, to}}
    graph = PoseGraph.follow(graph, id, to)
    {%{loops | graph: graph, frame: frame, moves: moves}, {:closed, from, to}}
  end

  # The graph's chain of scan matches drifts less than the localizer
  # against the map it draws: when the newest node lies `follow_distance`
  # m or `follow_angle` rad from the localizer's estimate of it, the map
  # is drawn again at the graph's poses and the localizer moved onto it.
  defp follow(%{params: p} = loops, graph, id) do
    {x, y, th} = to = PoseGraph.pose(graph, id)
    {ex, ey, eth} = from = PoseGraph.estimate(graph, id)

    if p.follow_distance > 0 and
         (:math.sqrt((x - ex) ** 2 + (y - ey) ** 2) >= p.follow_distance or
            abs(normalize_angle(th - eth)) >= p.follow_angle),
       do: move_frame(loops, graph, id, from, to),
       else: {%{loops | graph: graph}, :none}
  end

  # whether a node moved far enough for the map to be drawn again
  defp shifted?(before, now, p) do
    Enum.any?(now.nodes, fn {id, {x, y, th}} ->
      case before.nodes do
        %{^id => {x0, y0, th0}} ->
          :math.sqrt((x - x0) ** 2 + (y - y0) ** 2) >= p.redraw_distance or
            abs(normalize_angle(th - th0)) >= p.redraw_angle

        _ ->
          false
      end
    end)
  end

  defp carry_to(_loops, pose, :none), do: pose
  defp carry_to(_loops, pose, {:closed, from, to}), do: move(pose, from, to)

  defp keep(loops, tag, scan, pose) do
    # a scan of another length than its sensor's first is not kept
    if length(scan.ranges) == loops.meta[tag].beams and
         (loops.kept == nil or moved?(loops.kept, pose, loops.params)) do
      node = PoseGraph.last(loops.graph)
      rel = EKF.relative(PoseGraph.estimate(loops.graph, node), pose)
      ranges = for r <- scan.ranges, into: <<>>, do: <<range(r)::float-32-native>>

      %{
        loops
        | scans: [{node, rel, tag, ranges} | loops.scans],
          count: loops.count + 1,
          kept: pose
      }
    else
      loops
    end
  end

  defp range(r) when is_number(r), do: r * 1.0
  defp range(_), do: -1.0

  defp moved?({x0, y0, th0}, {x, y, th}, p) do
    :math.sqrt((x - x0) ** 2 + (y - y0) ** 2) >= p.keep_distance or
      abs(normalize_angle(th - th0)) >= p.keep_angle
  end

  defp meta(scan) do
    scan
    |> Map.take([:angle_min, :angle_increment, :range_max, :range_min])
    |> Map.put(:beams, length(scan.ranges))
  end

  @doc """
  Draws the kept scans into `grid` (a fresh map) at their nodes' poses
  now, with the robot's footprint (`discs`, as
  `SensedGrid.add_footprint/4`) at each; `mounts` maps each laser's tag
  to where it sits on the robot. Returns the grid.
  """
  @spec redraw(t(), SensedGrid.t(), %{atom() => pose()}, list()) :: SensedGrid.t()
  def redraw(%__MODULE__{} = loops, grid, mounts, discs) do
    scans = Enum.reverse(loops.scans)

    scans
    |> Enum.group_by(fn {_node, _rel, tag, _ranges} -> tag end)
    |> Enum.each(fn {tag, kept} ->
      mount = Map.fetch!(mounts, tag)
      meta = loops.meta[tag]

      poses =
        for {node, rel, _tag, _ranges} <- kept, into: <<>> do
          {x, y, th} = EKF.motion(EKF.motion(PoseGraph.pose(loops.graph, node), rel), mount)
          <<x::float-native, y::float-native, th::float-native>>
        end

      ranges = for {_node, _rel, _tag, r} <- kept, into: <<>>, do: r
      beams = div(byte_size(elem(hd(kept), 3)), 4)
      SensedGrid.replay_lasers(grid, poses, ranges, beams, meta)
    end)

    # the ground the robot stood on, every 10 cm of its way
    scans
    |> Enum.map(fn {node, rel, _tag, _ranges} ->
      EKF.motion(PoseGraph.pose(loops.graph, node), rel)
    end)
    |> Enum.dedup_by(fn {x, y, _} -> {round(x / 0.1), round(y / 0.1)} end)
    |> Enum.each(&SensedGrid.add_footprint(grid, &1, discs))

    grid
  end

  @doc """
  A pose estimated in map frame `frame` brought into the current one;
  nil when it is older than the last move before it (too old to carry).
  """
  @spec carry(t(), pose(), non_neg_integer()) :: pose() | nil
  def carry(%__MODULE__{frame: current}, pose, frame) when frame == current, do: pose

  def carry(%__MODULE__{frame: current, moves: moves}, pose, frame) when frame == current - 1 do
    {from, to} = Map.fetch!(moves, current)
    move(pose, from, to)
  end

  def carry(%__MODULE__{}, _pose, _frame), do: nil

  # the rigid motion taking `from` to `to`, applied to `pose`
  defp move(pose, from, to), do: EKF.motion(to, EKF.relative(from, pose))
end
