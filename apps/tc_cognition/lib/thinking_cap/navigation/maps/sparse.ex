defmodule ThinkingCap.Navigation.Maps.Sparse do
  @moduledoc false
  # A cell binary from a sparse set of cell values over a default.

  @doc false
  @spec to_binary([{non_neg_integer(), 0..255}], non_neg_integer(), 0..255) :: binary()
  def to_binary(values, size, default) do
    {parts, pos} =
      values
      |> Enum.sort()
      |> Enum.reduce({[], 0}, fn {index, value}, {parts, pos} ->
        {[<<value>>, :binary.copy(<<default>>, index - pos) | parts], index + 1}
      end)

    IO.iodata_to_binary(Enum.reverse([:binary.copy(<<default>>, size - pos) | parts]))
  end
end
