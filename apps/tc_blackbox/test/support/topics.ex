defmodule ThinkingCap.BlackBox.Test.Topics do
  @moduledoc false
  # A recording's messages by kind: Foxglove's (JSON) and the whole
  # terms (`/etf/...`, Erlang's external term format).
  alias ThinkingCap.MCAP.Reader

  @doc "The messages on channels of `encoding` (\"json\" or \"etf\")."
  @spec messages(Reader.t(), String.t()) :: [ThinkingCap.MCAP.Message.t()]
  def messages(mcap, encoding),
    do: Enum.filter(mcap.messages, &(mcap.channels[&1.channel_id].message_encoding == encoding))

  @doc "The messages per topic, counted, of channels of `encoding`."
  @spec counts(Reader.t(), String.t()) :: %{String.t() => non_neg_integer()}
  def counts(mcap, encoding),
    do: mcap |> messages(encoding) |> Enum.frequencies_by(&mcap.channels[&1.channel_id].topic)

  @doc "The terms recorded whole on `topic`, in order."
  @spec terms(Reader.t(), String.t()) :: [term()]
  def terms(mcap, topic) do
    for m <- mcap.messages,
        mcap.channels[m.channel_id].topic == topic,
        do: :erlang.binary_to_term(m.data)
  end
end
