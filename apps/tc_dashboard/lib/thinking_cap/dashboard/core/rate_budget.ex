defmodule ThinkingCap.Dashboard.Core.RateBudget do
  @moduledoc false
  # A socket's message-rate budget: a token bucket (`rate` messages a
  # second, bursts of `burst`) and a count of the messages it dropped.
  #
  # The drop count is forgiven only once the bucket has filled up again,
  # that is once the client has kept under the rate for `burst / rate`
  # seconds; not on each admitted message. A flooder is admitted a message
  # whenever a token trickles in, and must still be found out however fast
  # or slow its flood arrives (`flooding?/2`).

  defstruct rate: 100, burst: 200, tokens: 200.0, last: nil, dropped: 0, warned: 0

  @type t :: %__MODULE__{
          rate: pos_integer(),
          burst: pos_integer(),
          tokens: float(),
          last: integer() | nil,
          dropped: non_neg_integer(),
          warned: non_neg_integer()
        }

  @doc "A full budget of `rate` messages a second and bursts of `burst`."
  @spec new(pos_integer(), pos_integer()) :: t()
  def new(rate, burst), do: %__MODULE__{rate: rate, burst: burst, tokens: burst * 1.0}

  @doc "Admits or drops one message arriving at `now_ms` (a monotonic clock)."
  @spec admit(t(), integer()) :: {:ok | :drop, t()}
  def admit(%__MODULE__{} = budget, now_ms) do
    elapsed = if budget.last, do: max(now_ms - budget.last, 0), else: 0
    tokens = min(budget.burst * 1.0, budget.tokens + elapsed * budget.rate / 1000)

    budget =
      if tokens >= budget.burst,
        do: %{budget | dropped: 0, warned: 0, last: now_ms},
        else: %{budget | last: now_ms}

    if tokens >= 1.0,
      do: {:ok, %{budget | tokens: tokens - 1.0}},
      else: {:drop, %{budget | tokens: tokens, dropped: budget.dropped + 1}}
  end

  @doc "Whether the client has had `limit` messages dropped without a pause."
  @spec flooding?(t(), pos_integer()) :: boolean()
  def flooding?(%__MODULE__{dropped: dropped}, limit), do: dropped >= limit

  @doc """
  Whether this drop deserves an error reply: the first one, then one every
  `every` drops. Returns the budget with the warning recorded.
  """
  @spec warn?(t(), pos_integer()) :: {boolean(), t()}
  def warn?(%__MODULE__{} = budget, every) do
    if budget.warned == 0 or budget.dropped - budget.warned >= every,
      do: {true, %{budget | warned: budget.dropped}},
      else: {false, budget}
  end
end
