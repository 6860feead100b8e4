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
  def to_ejson(nil), do: nil
  def to_ejson(true), do: true
  def to_ejson(false), do: false
  def to_ejson(term) when is_atom(term), do: Atom.to_string(term)
  def to_ejson(term) when is_number(term), do: term

  def to_ejson(term) when is_binary(term) do
    if String.valid?(term), do: term, else: %{"base64" => Base.encode64(term)}
  end

  def to_ejson(term) when is_bitstring(term), do: %{"bits" => inspect(term)}
  def to_ejson(term) when is_list(term), do: list(term)
  def to_ejson(term) when is_tuple(term), do: term |> Tuple.to_list() |> list()

  def to_ejson(%module{} = struct) when is_atom(module) do
    struct
    |> Map.from_struct()
    |> map()
    |> Map.put("__struct__", inspect(module))
  end

  def to_ejson(term) when is_map(term), do: map(term)
  def to_ejson(term), do: inspect(term)

  defp map(term), do: Map.new(term, fn {k, v} -> {key(k), to_ejson(v)} end)

  defp list([]), do: []
  defp list([h | t]) when is_list(t), do: [to_ejson(h) | list(t)]
  # an improper list
  defp list([h | t]), do: [to_ejson(h), to_ejson(t)]

  defp key(k) when is_atom(k), do: Atom.to_string(k)
  defp key(k) when is_binary(k), do: if(String.valid?(k), do: k, else: inspect(k))
  defp key(k) when is_number(k), do: to_string(k)
  defp key(k), do: inspect(k)
end
