defmodule ThinkingCap.Navigation.OdometryCalibration do
  @moduledoc """
  Learns an odometry's systematic heading errors from the corrections a
  localizer's scans make, and takes them out of the odometry's moves.

  A differential robot whose wheelbase is off by 0.5 % turns 0.5 % more
  or less than its odometry says; one whose wheels differ in size by
  0.2 % curves a little for every metre it drives. A localizer that
  holds the robot to a map corrects both, scan by scan; but where the map
  is being built at the same estimates (SLAM) part of each error lands in
  the map before a scan can say so. Each correction of the heading `δ`
  that a scan makes is fitted, by least squares with exponential
  forgetting, as `δ = a · r + b · d`, where `r` is the turn and `d` the
  signed distance the odometry reported since the scan before. The moves
  then apply `turn · (1 + a) + b · distance`.

  `a` and `b` stay 0 until enough turning and driving has been seen
  (a ridge term holds them there), and are bounded (`max_scale`,
  `max_drift`): a few wild corrections cannot make the odometry worse
  than it is.
  """

  defstruct a: 0.0,
            b: 0.0,
            srr: 0.0,
            srd: 0.0,
            sdd: 0.0,
            sr: 0.0,
            sd: 0.0,
            forget: 0.999,
            ridge: 0.2,
            max_scale: 0.05,
            max_drift: 0.05

  @type t :: %__MODULE__{}

  @doc """
  A calibration that changes nothing yet. Options: `forget` (per
  correction, default 0.999), `ridge` (default 0.2, in rad² and m²: how
  much turning and driving it takes before the fit moves), `max_scale`
  (0.05: `|a|`), `max_drift` (0.05 rad/m: `|b|`).
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []), do: struct(__MODULE__, opts)

  @doc """
  Takes a heading correction `delta` (rad) that a scan made after the
  odometry reported a turn `turn` (rad, signed, as the odometry said it)
  and a distance `distance` (m, signed: negative backwards).
  """
  @spec learn(t(), float(), float(), float()) :: t()
  def learn(%__MODULE__{} = c, turn, distance, delta) do
    f = c.forget

    c = %{
      c
      | srr: f * c.srr + turn * turn,
        srd: f * c.srd + turn * distance,
        sdd: f * c.sdd + distance * distance,
        sr: f * c.sr + turn * delta,
        sd: f * c.sd + distance * delta
    }

    # (XᵀX + ridge·I) [a b]ᵀ = Xᵀδ
    {m11, m12, m22} = {c.srr + c.ridge, c.srd, c.sdd + c.ridge}
    det = m11 * m22 - m12 * m12
    a = (m22 * c.sr - m12 * c.sd) / det
    b = (m11 * c.sd - m12 * c.sr) / det
    %{c | a: clamp(a, c.max_scale), b: clamp(b, c.max_drift)}
  end

  defp clamp(v, limit), do: max(-limit, min(limit, v))

  @doc """
  An odometry move `{dx, dy, dθ}` (robot frame) with the learned errors
  taken out of its turn.
  """
  @spec apply_to(t(), {float(), float(), float()}) :: {float(), float(), float()}
  def apply_to(%__MODULE__{a: a, b: b}, {dx, dy, dth}) do
    {dx, dy, dth * (1 + a) + b * signed_distance(dx, dy)}
  end

  @doc "The distance of a move, negative when it went backwards."
  @spec signed_distance(number(), number()) :: float()
  def signed_distance(dx, dy) do
    d = :math.sqrt(dx * dx + dy * dy)
    if dx < 0, do: -d, else: d
  end

  @doc "What it has learned: `%{turn_scale: 1 + a, turn_per_metre: b}`."
  @spec learned(t()) :: %{turn_scale: float(), turn_per_metre: float()}
  def learned(%__MODULE__{a: a, b: b}), do: %{turn_scale: 1 + a, turn_per_metre: b}
end
