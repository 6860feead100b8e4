defmodule ThinkingCap.BlackBox.Core.JSON do
  @moduledoc false
  # Any term as JSON iodata, written in one pass and without a crash:
  # atoms become strings (nil null, booleans booleans), tuples and lists
  # arrays (an improper list's tail its last element), structs objects
  # with their "__struct__", binaries that are not UTF-8 `{"base64": ...}`,
  # pids, references, ports and functions their printed form. Floats from
  # 0.01 up are written to the millionth (a micrometre, a microradian:
  # what a viewer needs, and their last digits compress badly), smaller
  # ones with every digit (the shortest form that reads back the same);
  # the recorder keeps the exact terms beside.
  #
  # Written here rather than through jiffy: the recorder turns every
  # tuple into JSON, and for its small terms building the iodata in
  # Erlang costs a fraction of a NIF call's (jiffy's encoder makes a
  # resource and a buffer each call): 1.5 µs for a pose message against
  # 15, on the bench's machine.

  alias ThinkingCap.BlackBox.Core.JSON.Native

  @spec encode(term()) :: iodata()
  def encode(term), do: value(term)

  @doc false
  # The same JSON, written in C into one binary when the term allows
  # (JSON.Native): no iodata on the caller's heap. The recorder's payloads.
  @spec fast(term()) :: iodata()
  def fast(term) do
    case Native.value(term) do
      false -> value(term)
      json -> json
    end
  end

  @doc false
  # a number: an integer as it is, a float to the millionth (from 0.01 up)
  @spec number(number()) :: binary()
  def number(x) when is_integer(x), do: Integer.to_string(x)
  def number(x) when is_float(x), do: float(x)

  defp float(x) when (x >= 0.01 and x < 1.0e15) or (x <= -0.01 and x > -1.0e15),
    do: :erlang.float_to_binary(x, [{:decimals, 6}, :compact])

  defp float(x), do: :erlang.float_to_binary(x, [:short])

  @spec value(term()) :: iodata()
  def value(nil), do: "null"
  def value(true), do: "true"
  def value(false), do: "false"
  def value(x) when is_atom(x), do: string(Atom.to_string(x))
  def value(x) when is_integer(x), do: Integer.to_string(x)
  def value(x) when is_float(x), do: float(x)

  def value(x) when is_binary(x) do
    if String.valid?(x), do: string(x), else: ["{\"base64\":\"", Base.encode64(x), "\"}"]
  end

  def value(x) when is_bitstring(x), do: ["{\"bits\":", string(inspect(x)), ?}]
  def value([]), do: "[]"
  def value([h | t]), do: [?[, value(h) | rest(t)]
  def value(x) when is_tuple(x), do: value(Tuple.to_list(x))

  def value(%module{} = struct) when is_atom(module) do
    fields = Map.from_struct(struct)
    object(fields, ["\"__struct__\":", string(inspect(module))])
  end

  def value(x) when is_map(x), do: object(x, [])
  def value(x), do: string(inspect(x))

  # the elements after a list's first: `,x` each, then `]`; an improper
  # list's tail as its last element
  defp rest([]), do: [?]]
  defp rest([h | t]), do: [?,, value(h) | rest(t)]
  defp rest(tail), do: [?,, value(tail), ?]]

  defp object(map, first) do
    members = :maps.fold(fn k, v, acc -> [?,, key(k), ?:, value(v) | acc] end, [], map)

    case {members, first} do
      {[], []} -> "{}"
      {[_comma | members], []} -> [?{, members, ?}]
      {members, first} -> [?{, first, members, ?}]
    end
  end

  defp key(k) when is_atom(k), do: string(Atom.to_string(k))
  defp key(k) when is_binary(k), do: if(String.valid?(k), do: string(k), else: string(inspect(k)))
  defp key(k) when is_number(k), do: [?", number(k), ?"]
  defp key(k), do: string(inspect(k))

  @doc false
  # a UTF-8 string, quoted, escaped where JSON needs it
  @spec string(binary()) :: iodata()
  def string(s) do
    if plain?(s), do: [?", s, ?"], else: [?", escape(s), ?"]
  end

  defp plain?(<<c, rest::binary>>) when c >= 0x20 and c != ?" and c != ?\\, do: plain?(rest)
  defp plain?(<<>>), do: true
  defp plain?(_), do: false

  defp escape(s), do: for(<<c <- s>>, into: "", do: escape_byte(c))

  defp escape_byte(?"), do: "\\\""
  defp escape_byte(?\\), do: "\\\\"
  defp escape_byte(?\n), do: "\\n"
  defp escape_byte(?\r), do: "\\r"
  defp escape_byte(?\t), do: "\\t"

  defp escape_byte(c) when c < 0x20,
    do: "\\u00" <> String.pad_leading(Integer.to_string(c, 16), 2, "0")

  defp escape_byte(c), do: <<c>>
end
