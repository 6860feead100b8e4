defmodule ThinkingCap.Perception.LPS do
  @moduledoc """
  The Local Perceptual Space: what the robot knows of its surroundings,
  centred on the robot and expressed in its frame (x forward, y left),
  fused from its range sensors over time (`ThinkingCap.Perception`) and
  published as `{:lps, robot, %LPS{}}`.

    * `bins` - the nearest obstacle in each of `n` equal sectors around the
      robot (a tuple of distances in metres, at most `range`): sector `i`
      covers robot-frame angles `[-π + i·2π/n, -π + (i + 1)·2π/n)`;
    * `evidence` - fuzzy occupancy evidence around the robot: points
      `{x, y, occupied, empty}` with separate degrees of "occupied" and
      "empty" in [0, 1], accumulated over readings and forgotten over time;
    * `segments` - straight walls extracted from it, `{{x1, y1}, {x2, y2}}`;
    * `doors` - openings between wall ends a robot fits through,
      `%{centre: {x, y}, width: m, heading: rad}` (heading: the direction
      through the opening, away from the robot);
    * `pose` - the odometry pose the LPS was built at; `stamp` - its time.

  Behaviours read it through `min_distance/3` and `distance_at/2`.
  """

  import ThinkingCap.Geometry, only: [normalize_angle: 1]

  defstruct robot: nil,
            stamp: 0.0,
            pose: {0.0, 0.0, 0.0},
            range: 5.0,
            n: 72,
            bins: nil,
            evidence: [],
            segments: [],
            doors: []

  @type point :: {float(), float()}
  @type t :: %__MODULE__{
          robot: atom() | nil,
          stamp: float(),
          pose: {float(), float(), float()},
          range: float(),
          n: pos_integer(),
          bins: tuple(),
          evidence: [{float(), float(), float(), float()}],
          segments: [{point(), point()}],
          doors: [%{centre: point(), width: float(), heading: float()}]
        }

  @two_pi 2 * :math.pi()

  @doc "An LPS seeing nothing within `range` (all sectors at `range`)."
  @spec empty(keyword()) :: t()
  def empty(opts \\ []) do
    n = Keyword.get(opts, :n, 72)
    range = Keyword.get(opts, :range, 5.0) * 1.0
    %__MODULE__{n: n, range: range, bins: Tuple.duplicate(range, n), robot: opts[:robot]}
  end

  @doc """
  An LPS from robot-frame obstacle points (for tests and simple sensors):
  each point shortens the sector it falls in.
  """
  @spec from_points([point()], keyword()) :: t()
  def from_points(points, opts \\ []) do
    lps = empty(opts)

    bins =
      Enum.reduce(points, lps.bins, fn {x, y}, bins ->
        d = :math.sqrt(x * x + y * y)
        i = sector(lps, :math.atan2(y, x))
        if d < elem(bins, i), do: put_elem(bins, i, d), else: bins
      end)

    %{lps | bins: bins}
  end

  @doc "The sector index of a robot-frame angle."
  @spec sector(t(), number()) :: non_neg_integer()
  def sector(%__MODULE__{n: n}, angle) do
    a = normalize_angle(angle)
    min(n - 1, floor((a + :math.pi()) / @two_pi * n))
  end

  @doc "The centre angle of sector `i`."
  @spec sector_angle(t(), non_neg_integer()) :: float()
  def sector_angle(%__MODULE__{n: n}, i), do: -:math.pi() + (i + 0.5) * @two_pi / n

  @doc "The nearest obstacle in the direction `angle` (robot frame)."
  @spec distance_at(t(), number()) :: float()
  def distance_at(%__MODULE__{bins: bins} = lps, angle), do: elem(bins, sector(lps, angle))

  @doc """
  The nearest obstacle between robot-frame angles `from` and `to`, going
  counter-clockwise from `from` (so `min_distance(lps, -0.5, 0.5)` is the
  front and `min_distance(lps, 2.5, -2.5)` the back).
  """
  @spec min_distance(t(), number(), number()) :: float()
  def min_distance(%__MODULE__{n: n, bins: bins} = lps, from, to) do
    first = sector(lps, from)
    last = sector(lps, to)
    count = rem(last - first + n, n) + 1

    Enum.reduce(0..(count - 1), lps.range, fn k, acc ->
      min(acc, elem(bins, rem(first + k, n)))
    end)
  end
end
