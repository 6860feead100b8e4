defmodule ThinkingCap.Dashboard.Core.JSON do
  @moduledoc false
  # JSON for the dashboard and rosbridge, on Debian's jiffy. Blackboard
  # payloads are Elixir terms: encode/1 maps them to JSON the way a browser
  # wants to read them (atoms → strings, tuples → arrays, structs → objects,
  # binaries that are not UTF-8 → base64 strings, pids and refs → their
  # printed form); decode/1 never raises.

  @doc "Encodes any term as JSON (iodata)."
  @spec encode!(term()) :: iodata()
  def encode!(term), do: :jiffy.encode(to_ejson(term), [:use_nil])

  @doc "Decodes a JSON text: objects become maps with binary keys."
  @spec decode(binary()) :: {:ok, term()} | {:error, String.t()}
  def decode(text) when is_binary(text) do
    {:ok, :jiffy.decode(text, [:return_maps, :use_nil, :dedupe_keys])}
  catch
    :error, {position, reason} when is_integer(position) ->
      {:error,
       "invalid JSON at byte #{position}: #{reason |> to_string() |> String.replace("_", " ")}"}

    kind, reason ->
      {:error, "invalid JSON: #{inspect({kind, reason})}"}
  end

  def decode(_other), do: {:error, "not a text"}

  @doc "The JSON-ready form of a term (jiffy's EJSON with maps)."
  @spec to_ejson(term()) :: term()
  def to_ejson(nil), do: nil
  def to_ejson(true), do: true
  def to_ejson(false), do: false
  def to_ejson(term) when is_atom(term), do: Atom.to_string(term)
  def to_ejson(term) when is_integer(term), do: term
  def to_ejson(term) when is_float(term), do: term

  def to_ejson(term) when is_binary(term) do
    if String.valid?(term), do: term, else: Base.encode64(term)
  end

  def to_ejson(term) when is_list(term), do: list(term)
  def to_ejson(term) when is_tuple(term), do: term |> Tuple.to_list() |> list()

  def to_ejson(%_{} = struct), do: struct |> Map.from_struct() |> to_ejson()

  def to_ejson(term) when is_map(term),
    do: Map.new(term, fn {k, v} -> {key(k), to_ejson(v)} end)

  def to_ejson(term), do: inspect(term)

  defp list([]), do: []
  defp list([h | t]) when is_list(t), do: [to_ejson(h) | list(t)]
  # an improper list
  defp list([h | t]), do: [to_ejson(h), to_ejson(t)]

  defp key(k) when is_binary(k), do: k
  defp key(k) when is_atom(k), do: Atom.to_string(k)
  defp key(k) when is_number(k), do: to_string(k)
  defp key(k), do: inspect(k)
end
