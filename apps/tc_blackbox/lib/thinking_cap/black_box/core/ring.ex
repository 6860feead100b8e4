defmodule ThinkingCap.BlackBox.Core.Ring do
  @moduledoc false
  # The ring buffer's store, a pure value: the tuples received, oldest
  # first, each with its receipt time (ns since the epoch) and its size
  # (its external size in bytes). Bounded by age, bytes and count; the
  # oldest go first, and are counted.

  defstruct queue: :queue.new(),
            count: 0,
            bytes: 0,
            dropped: 0,
            max_bytes: 0,
            max_messages: 0

  @type entry :: {time_ns :: integer(), tuple(), bytes :: non_neg_integer()}
  @type t :: %__MODULE__{}

  @spec new(pos_integer(), pos_integer()) :: t()
  def new(max_bytes, max_messages),
    do: %__MODULE__{max_bytes: max_bytes, max_messages: max_messages}

  # Adds a tuple received at `time_ns`, then drops the oldest past the bounds.
  @spec push(t(), integer(), tuple()) :: t()
  def push(ring, time_ns, tuple) do
    size = :erlang.external_size(tuple)

    %{
      ring
      | queue: :queue.in({time_ns, tuple, size}, ring.queue),
        count: ring.count + 1,
        bytes: ring.bytes + size
    }
    |> bound()
  end

  defp bound(%{count: c, bytes: b, max_messages: mc, max_bytes: mb} = ring)
       when c > mc or b > mb,
       do: ring |> drop_oldest(true) |> bound()

  defp bound(ring), do: ring

  # Forgets what was received before `time_ns` (aged out: not a drop).
  @spec forget_before(t(), integer()) :: t()
  def forget_before(ring, time_ns) do
    case :queue.peek(ring.queue) do
      {:value, {t, _, _}} when t < time_ns -> ring |> drop_oldest(false) |> forget_before(time_ns)
      _ -> ring
    end
  end

  defp drop_oldest(ring, counted?) do
    {{:value, {_, _, size}}, queue} = :queue.out(ring.queue)

    %{
      ring
      | queue: queue,
        count: ring.count - 1,
        bytes: ring.bytes - size,
        dropped: if(counted?, do: ring.dropped + 1, else: ring.dropped)
    }
  end

  # The entries received from `from_ns` to `to_ns` (both included), oldest first.
  @spec slice(t(), integer(), integer()) :: [entry()]
  def slice(ring, from_ns, to_ns) do
    for {t, _, _} = e <- :queue.to_list(ring.queue), t >= from_ns, t <= to_ns, do: e
  end

  # The tuples whose tag (first element) is in `tags` (every tuple for
  # `:all`), oldest first, each with its receipt time.
  @spec select(t(), [atom()] | :all) :: [{integer(), tuple()}]
  def select(ring, :all), do: for({t, tuple, _} <- :queue.to_list(ring.queue), do: {t, tuple})

  def select(ring, tags) do
    tags = MapSet.new(tags)

    for {t, tuple, _} <- :queue.to_list(ring.queue),
        MapSet.member?(tags, elem(tuple, 0)),
        do: {t, tuple}
  end

  # The receipt time of the oldest entry, or nil.
  @spec oldest(t()) :: integer() | nil
  def oldest(ring) do
    case :queue.peek(ring.queue) do
      {:value, {t, _, _}} -> t
      :empty -> nil
    end
  end
end
