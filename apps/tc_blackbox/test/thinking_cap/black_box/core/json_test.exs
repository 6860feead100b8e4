defmodule ThinkingCap.BlackBox.Core.JSONTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Core.JSON

  defp text(term), do: term |> JSON.encode() |> IO.iodata_to_binary()
  defp decode(term), do: :jiffy.decode(text(term), [:return_maps, :use_nil])

  test "numbers: integers as they are, floats to the millionth from 0.01 up" do
    for x <- [0, -7, 123_456_789_012_345_678_901_234_567_890, 0.1, -2.5, 1.0e-7, 6.02e23, -0.0] do
      assert decode(x) == x
    end

    assert text(0.1) == "0.1"
    assert text([1.5, 2, 3.0]) == "[1.5,2,3.0]"
    assert text(2.7240969296835993) == "2.724097"
    assert text(-0.7853981633974483) == "-0.785398"
    assert text(0.0012345678901) == "0.0012345678901"
    assert text(1.0e15) == "1.0e15"
  end

  test "strings are quoted and escaped where JSON needs it" do
    for s <- ["", "plain", "héllo ✓", "quote \" and \\ back", "tab\tnew\nline\r", <<1, 31>>] do
      assert decode(s) == s
    end

    assert text("a\"b") == ~S("a\"b")
    assert text(<<1>>) == ~S("\u0001")
  end

  test "atoms, tuples, lists and maps" do
    assert decode(nil) == nil
    assert decode(true) == true and decode(false) == false
    assert decode(:null) == "null"
    assert decode(:go) == "go"
    assert decode({:velocity, 0.5, -1}) == ["velocity", 0.5, -1]
    assert decode([]) == [] and decode({}) == []
    assert decode([1 | 2]) == [1, 2]
    assert decode([:a, [:b | :c]]) == ["a", ["b", "c"]]
    assert decode(%{}) == %{}

    assert decode(%{:a => 1, "b" => [2], 3 => :x, {:k, 1} => nil, :null => 0}) ==
             %{"a" => 1, "b" => [2], "3" => "x", "{:k, 1}" => nil, "null" => 0}
  end

  test "structs, bad UTF-8, bits and the rest" do
    assert decode(%URI{host: "h", port: 80})["__struct__"] == "URI"
    assert decode(%URI{host: "h", port: 80})["port"] == 80
    assert decode(<<255, 0>>) == %{"base64" => Base.encode64(<<255, 0>>)}
    assert decode(%{<<255>> => 1}) == %{inspect(<<255>>) => 1}
    assert decode(<<1::3>>) == %{"bits" => inspect(<<1::3>>)}
    assert decode(self()) == inspect(self())
    ref = make_ref()
    assert decode([ref]) == [inspect(ref)]
  end

  test "a nested term reads back as jiffy reads its own JSON of it" do
    term = %{
      pose: [1.25, -3.0, 0.001],
      detections: [%{id: "b1", range: 2.5, bearing: -0.25}, %{id: "b2", range: 9.0, bearing: 1.5}],
      mode: "auto",
      n: 72,
      bins: Enum.map(1..72, &(&1 / 7))
    }

    rounded = %{term | bins: Enum.map(term.bins, &(round(&1 * 1.0e6) / 1.0e6))}
    assert decode(term) == :jiffy.decode(:jiffy.encode(rounded), [:return_maps, :use_nil])
  end
end
