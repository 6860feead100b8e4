defmodule ThinkingCap.BlackBox.Core.JSON do
  @moduledoc false
  # Any term as JSON, on Debian's jiffy, without a crash: atoms become
  # strings (nil null, booleans booleans), tuples and lists arrays (an
  # improper list's tail its last element), structs objects with their
  # "__struct__", binaries that are not UTF-8 `{"base64": ...}`, pids,
  # references, ports and functions their printed form. Floats keep every
  # digit (jiffy writes the shortest form that reads back the same).

  @spec encode(term()) :: iodata()
  def encode(term), do: :jiffy.encode(to_ejson(term), [:use_nil])

  @spec to_ejson(term()) :: term()
  # jiffy writes atoms as strings itself (nil, with :use_nil, as null,
  # booleans as booleans): all but :null, which it would write as null
  def to_ejson(:null), do: "null"
  def to_ejson(term) when is_atom(term), do: term
  def to_ejson(term) when is_number(term), do: term

  def to_ejson(term) when is_binary(term) do
    if String.valid?(term), do: term, else: %{"base64" => Base.encode64(term)}
  end

  def to_ejson(term) when is_bitstring(term), do: %{"bits" => inspect(term)}

  # numbers as they are (a scan's ranges, a point): nothing to convert
  def to_ejson(term) when is_list(term),
    do: if(numbers?(term), do: term, else: list(term))

  def to_ejson(term) when is_tuple(term) do
    list = Tuple.to_list(term)
    if numbers?(list), do: list, else: list(list)
  end

  def to_ejson(%module{} = struct) when is_atom(module) do
    struct
    |> Map.from_struct()
    |> map()
    |> Map.put("__struct__", inspect(module))
  end

  def to_ejson(term) when is_map(term), do: map(term)
  def to_ejson(term), do: inspect(term)

  # keys jiffy writes as they are (atoms, UTF-8 strings) stay
  defp map(term) do
    if Enum.all?(Map.keys(term), &plain_key?/1),
      do: :maps.map(fn _k, v -> to_ejson(v) end, term),
      else: Map.new(term, fn {k, v} -> {key(k), to_ejson(v)} end)
  end

  defp plain_key?(:null), do: false
  defp plain_key?(k) when is_atom(k), do: true
  defp plain_key?(k) when is_binary(k), do: String.valid?(k)
  defp plain_key?(_k), do: false

  # a proper list of numbers only
  defp numbers?([]), do: true
  defp numbers?([h | t]) when is_number(h), do: numbers?(t)
  defp numbers?(_), do: false

  defp list([]), do: []
  defp list([h | t]) when is_list(t), do: [to_ejson(h) | list(t)]
  # an improper list
  defp list([h | t]), do: [to_ejson(h), to_ejson(t)]

  defp key(k) when is_atom(k), do: Atom.to_string(k)
  defp key(k) when is_binary(k), do: if(String.valid?(k), do: k, else: inspect(k))
  defp key(k) when is_number(k), do: to_string(k)
  defp key(k), do: inspect(k)
end
