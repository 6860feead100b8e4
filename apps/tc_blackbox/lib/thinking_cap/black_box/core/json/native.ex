defmodule ThinkingCap.BlackBox.Core.JSON.Native do
  @moduledoc false
  # Core.JSON's rules in C (c_src/tc_json.c, built into
  # priv/lib/tc_json.so): a term's JSON as one binary, for the terms the
  # recorder meets most, so that their JSON does not fill its heap.
  # `value/1`, `tuple/3` and `tuple_etf/1` answer false for a term it leaves to Core.JSON (see the C
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
  def tuple_etf(etf), do: nif_tuple_etf(etf)

  # a list of numbers: floats to three decimals, integers as they are
  @spec millimetres(list()) :: binary()
  def millimetres(ranges), do: nif_millimetres(ranges)

  @doc false
  def nif_value(_term), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_tuple(_tag, _id, _payload), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_tuple_etf(_etf), do: :erlang.nif_error(:nif_not_loaded)
  @doc false
  def nif_millimetres(_ranges), do: :erlang.nif_error(:nif_not_loaded)
end
