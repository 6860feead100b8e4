defmodule ThinkingCap.Dashboard.Core.JSONTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Dashboard.Core.JSON

  defp roundtrip(term, opts \\ []),
    do: term |> JSON.encode!(opts) |> IO.iodata_to_binary() |> :jiffy.decode([:return_maps])

  test "terms become what a browser reads: atoms strings, tuples arrays, structs objects" do
    assert roundtrip(%{pose: {1.5, :r1, [true, nil]}, at: ~D[2026-11-22]}) ==
             %{
               "pose" => [1.5, "r1", [true, :null]],
               "at" => %{
                 "calendar" => "Elixir.Calendar.ISO",
                 "day" => 22,
                 "month" => 11,
                 "year" => 2026
               }
             }

    assert roundtrip(<<255, 0>>) == Base.encode64(<<255, 0>>)
    assert is_binary(roundtrip(self()))
  end

  test "decimals: floats rounded, their text short; small values kept whole" do
    ranges = [1.2345678901234567, 0.30000000000000004, 12.999999999]
    text = ranges |> JSON.encode!(decimals: 3) |> IO.iodata_to_binary()
    assert text == "[1.235,0.3,13.0]"
    # a variance of 1e-6 m² is not rounded to nothing
    assert roundtrip(%{cov: 1.234e-6}, decimals: 3) == %{"cov" => 1.234e-6}
    assert roundtrip(-2.71828, decimals: 2) == -2.72
    # without the option, every digit
    assert roundtrip(1.2345678901234567) == 1.2345678901234567
  end
end
