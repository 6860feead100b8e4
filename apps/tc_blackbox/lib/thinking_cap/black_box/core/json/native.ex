defmodule ThinkingCap.BlackBox.Core.JSON.Native do
  @moduledoc false
  # Core.JSON's rules in C (c_src/tc_json.c, built into
  # priv/lib/tc_json.so): a term's JSON as one binary, for the terms the
  # recorder meets most, so that their JSON does not fill its heap.
  # `value/1`, `tuple/3`, `tuple_etf/1` and `messages_etf/3` answer false for a term it leaves to Core.JSON (see the C
  # file); `millimetres/1` writes a scan's ranges.

  @on_load :load_nif

  defp load_nif do
    path = :filename.join(:code.priv_dir(:tc_blackbox), ~c"lib/tc_json")
    :erlang.load_nif(path, 0)
  end

  # a term's JSON, or false when Core.JSON must write it
  @spec value(term()) :: binary() | false
  def value(term), do: nif_value(term)

  # a thinkingcap.Tuple message's JSON, `{"tag":T,"robot":I,"payload":P}`
  # (each as value/1), or false when Core.JSON must write one of them
  @spec tuple(term(), term(), term()) :: binary() | false
  def tuple(tag, id, payload), do: nif_tuple(tag, id, payload)

  # tuple/3's JSON of `{tag, id, payload}` given as its external term
  # (`term_to_binary/1`), read without decoding it; false as tuple/3
  @spec tuple_etf(binary()) :: binary() | false
  def tuple_etf(etf) do
    case nif_messages_etf(:generic, etf, 0) do
      [json] -> json
      false -> false
    end
  end

  # A tuple's Foxglove messages' JSON (BlackBox.Foxglove's, `kind` as
  # Foxglove.kind/1 says, `:generic` a thinkingcap.Tuple) from its external
  # term, `ns` their time (the payload's stamp, else the log time); false
  # when it is not of that kind's shape or holds what Core.JSON writes
  @spec messages_etf(atom(), binary(), non_neg_integer()) :: [binary()] | false
  def messages_etf(kind, etf, ns), do: nif_messages_etf(kind, etf, ns)

  # a list of numbers: floats to three decimals, integers as they are
  @spec millimetres(list()) :: binary()
  def millimetres(ranges), do: nif_millimetres(ranges)

  @doc false
  def nif_value(_term), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_tuple(_tag, _id, _payload), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_messages_etf(_kind, _etf, _ns), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_millimetres(_ranges), do: :erlang.nif_error(:nif_not_loaded)
end
