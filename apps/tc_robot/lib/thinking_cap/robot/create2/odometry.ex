defmodule ThinkingCap.Robot.Create2.Odometry do
  @moduledoc """
  Dead reckoning from the Create 2's wheel encoders (packets 43 and 44):
  unsigned 16-bit counts that wrap at 65536, 508.8 counts per wheel
  revolution. Each new pair of counts moves the pose by the wheels' arcs
  (`ThinkingCap.Robot.Kinematics.integrate/3`); a step of more than half
  the counter's range is taken as a wrap the other way.

  A step no wheel could make (faster than the OI's 500 mm/s, with a
  generous margin, over the time since the previous counts, or over the
  stream periods of the frames it spans when the driver lost some) is
  not integrated: such counts came from a frame that passed its 8-bit
  checksum by chance. They become the new reference and `jumps` counts
  them. The frames count matters when several arrive in one read of the
  line, all with that read's stamp: a step over ten lost frames then
  came 0 s after the last counts.

  Speeds `v` (m/s) and `w` (rad/s) are the last step over the stream's
  period (15 ms): the robot samples its encoders on its own clock, so
  this is steadier than the frames' arrival times on a busy host.
  """

  alias ThinkingCap.Robot.Kinematics

  @counts_per_rev 508.8
  @period 0.015
  # the fastest wheel (m/s), the margin on it, and counts always allowed
  @max_wheel_speed 0.5
  @margin 1.5
  @slack 50

  @typedoc "The odometry: pose, last counts (nil before the first), speeds."
  @type t :: %__MODULE__{
          pose: Kinematics.pose(),
          left: non_neg_integer() | nil,
          right: non_neg_integer() | nil,
          v: float(),
          w: float(),
          stamp: float() | nil,
          meters_per_count: float(),
          separation: float(),
          jumps: non_neg_integer()
        }
  defstruct pose: {0.0, 0.0, 0.0},
            left: nil,
            right: nil,
            v: 0.0,
            w: 0.0,
            stamp: nil,
            meters_per_count: 2 * :math.pi() * 0.036 / @counts_per_rev,
            separation: 0.235,
            jumps: 0

  @doc "The encoder counts per wheel revolution (508.8)."
  @spec counts_per_rev() :: float()
  def counts_per_rev, do: @counts_per_rev

  @doc "Odometry at the origin for wheels of `wheel_radius` (m), `separation` (m) apart."
  @spec new(number(), number()) :: t()
  def new(wheel_radius, separation),
    do: %__MODULE__{
      meters_per_count: 2 * :math.pi() * wheel_radius / @counts_per_rev,
      separation: separation / 1
    }

  @doc """
  Integrates a new pair of encoder counts read at `stamp` (s), `frames`
  stream frames after the last pair (1, more when frames between were
  lost). The first pair (and the first after `rebase/1`) only sets the
  reference.
  """
  @spec update(t(), non_neg_integer(), non_neg_integer(), number(), pos_integer()) :: t()
  def update(odo, left, right, stamp, frames \\ 1)

  def update(%__MODULE__{left: nil} = odo, left, right, stamp, _frames),
    do: %{odo | left: left, right: right, stamp: stamp, v: 0.0, w: 0.0}

  def update(%__MODULE__{} = odo, left, right, stamp, frames) do
    steps = {wrap(left - odo.left), wrap(right - odo.right)}

    if plausible?(odo, steps, stamp, frames),
      do: step(odo, steps, left, right, stamp),
      else: %{odo | left: left, right: right, stamp: stamp, jumps: odo.jumps + 1}
  end

  defp plausible?(odo, {sl, sr}, stamp, frames) do
    dt = max(stamp - (odo.stamp || stamp), frames * @period)
    allowed = @max_wheel_speed * @margin * dt / odo.meters_per_count + @slack
    abs(sl) <= allowed and abs(sr) <= allowed
  end

  defp step(odo, {sl, sr}, left, right, stamp) do
    dl = sl * odo.meters_per_count
    dr = sr * odo.meters_per_count
    d = (dl + dr) / 2
    dtheta = (dr - dl) / odo.separation

    %{
      odo
      | pose: Kinematics.integrate(odo.pose, {d, dtheta}, 1.0),
        left: left,
        right: right,
        stamp: stamp,
        v: d / @period,
        w: dtheta / @period
    }
  end

  @doc "Forgets the reference counts (the line was lost: the counts may have jumped); keeps the pose."
  @spec rebase(t()) :: t()
  def rebase(odo), do: %{odo | left: nil, right: nil, v: 0.0, w: 0.0}

  @doc "A counter step, taking wrap-around into account: in -32768..32767."
  @spec wrap(integer()) :: integer()
  def wrap(delta), do: Integer.mod(delta + 32_768, 65_536) - 32_768

  @doc "The odometry reading's payload."
  @spec reading(t()) :: map()
  def reading(odo) do
    %{
      pose: odo.pose,
      v: odo.v,
      w: odo.w,
      twist: {odo.v, odo.w},
      left_counts: odo.left,
      right_counts: odo.right,
      stamp: odo.stamp
    }
  end
end
