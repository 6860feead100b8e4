defmodule ThinkingCap.Dashboard.Core.JSON do
  @moduledoc false
  # JSON for the dashboard and rosbridge, on Debian's jiffy. Blackboard
  # payloads are Elixir terms: encode/1 maps them to JSON the way a browser
  # wants to read them (atoms → strings, tuples → arrays, structs → objects,
  # binaries that are not UTF-8 → base64 strings, pids and refs → their
  # printed form); decode/1 never raises.

  @doc """
  Encodes any term as JSON (iodata). `decimals: n` rounds floats of 0.001
  and above to n decimals (small ones, such as variances, are kept whole):
  a laser scan's ranges in millimetres rather than 17 digits each.
  """
  @spec encode!(term(), keyword()) :: iodata()
  def encode!(term, opts \\ []) do
    scale = if d = opts[:decimals], do: :math.pow(10, d)
    :jiffy.encode(to_ejson(term, scale), [:use_nil])
  end

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

  @doc "The JSON-ready form of a term (jiffy's EJSON with maps); `scale` rounds floats."
  @spec to_ejson(term(), float() | nil) :: term()
  def to_ejson(term, scale \\ nil)
  def to_ejson(nil, _scale), do: nil
  def to_ejson(true, _scale), do: true
  def to_ejson(false, _scale), do: false
  def to_ejson(term, _scale) when is_atom(term), do: Atom.to_string(term)
  def to_ejson(term, _scale) when is_integer(term), do: term

  def to_ejson(term, scale) when is_float(term) and is_float(scale) and abs(term) >= 1.0e-3,
    do: round(term * scale) / scale

  def to_ejson(term, _scale) when is_float(term), do: term

  def to_ejson(term, _scale) when is_binary(term) do
    if String.valid?(term), do: term, else: Base.encode64(term)
  end

  def to_ejson(term, scale) when is_list(term), do: list(term, scale)
  def to_ejson(term, scale) when is_tuple(term), do: term |> Tuple.to_list() |> list(scale)

  def to_ejson(%_{} = struct, scale), do: struct |> Map.from_struct() |> to_ejson(scale)

  def to_ejson(term, scale) when is_map(term),
    do: Map.new(term, fn {k, v} -> {key(k), to_ejson(v, scale)} end)

  def to_ejson(term, _scale), do: inspect(term)

  defp list([], _scale), do: []
  defp list([h | t], scale) when is_list(t), do: [to_ejson(h, scale) | list(t, scale)]
  # an improper list
  defp list([h | t], scale), do: [to_ejson(h, scale), to_ejson(t, scale)]

  defp key(k) when is_binary(k), do: k
  defp key(k) when is_atom(k), do: Atom.to_string(k)
  defp key(k) when is_number(k), do: to_string(k)
  defp key(k), do: inspect(k)
end
