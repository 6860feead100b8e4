defmodule ThinkingCap.BlackBox.Core.JSON.NativeTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Core.JSON
  alias ThinkingCap.BlackBox.Core.JSON.Native

  defp elixir(term), do: term |> JSON.value() |> IO.iodata_to_binary()

  # floats of every size, and the ones that round on a half
  defp random_float do
    x = (:rand.uniform() - 0.5) * :math.pow(10, :rand.uniform(60) - 30)

    Enum.random([
      x,
      Float.round(x, 3),
      Float.round(x, 6),
      Float.round(x, 4) + 0.0005,
      x + 5.0e-7,
      :rand.uniform(100_000) * 1.0e-5,
      :rand.uniform(1000) * 1.0e14,
      0.0,
      -0.0
    ])
  end

  defp random_term(0), do: random_leaf()

  defp random_term(depth) do
    case :rand.uniform(6) do
      1 -> Enum.map(1..:rand.uniform(5), fn _ -> random_term(depth - 1) end)
      2 -> List.to_tuple(Enum.map(1..:rand.uniform(4), fn _ -> random_term(depth - 1) end))
      3 -> Map.new(1..:rand.uniform(6), fn i -> {random_key(i), random_term(depth - 1)} end)
      4 -> %URI{host: "h", port: :rand.uniform(100), path: random_term(depth - 1)}
      _ -> random_leaf()
    end
  end

  defp random_key(i), do: Enum.random([:"k#{i}", "s#{i}", i, i + 0.5])

  defp random_leaf do
    Enum.random([
      random_float(),
      :rand.uniform(1_000_000) - 500_000,
      Enum.random([nil, true, false, :go, :null, :"a b"]),
      Enum.random(["", "plain", "quote \" and \\ back", "tab\tnew\nline", <<1, 31>>]),
      [],
      {}
    ])
  end

  test "floats are written as Core.JSON writes them" do
    for _ <- 1..20_000 do
      x = random_float()
      assert Native.value(x) == elixir(x), "#{inspect(x)}"
    end
  end

  test "random terms are written as Core.JSON writes them, byte for byte" do
    for _ <- 1..3_000 do
      term = random_term(3)
      assert Native.value(term) == elixir(term), inspect(term)
    end
  end

  test "a robot's payloads are written in C, not left to Core.JSON" do
    payloads = [
      %{stamp: 12.34, pose: {1.5, -2.25, 0.001}, velocity: {0.0, -0.0, 1.0e-5}, frame: :odom},
      %{stamp: 3.0, ranges: [0.5, 1.25, 5.0], hit: [true, false, true]},
      %{stamp: 1.0, beacons: [%{id: 3, range: 2.5, bearing: -0.75}], count: 1}
    ]

    for p <- payloads do
      assert is_binary(Native.value(p)) and Native.value(p) == elixir(p)
    end
  end

  test "a thinkingcap.Tuple message whole, as Core.JSON writes it" do
    erlang = fn tag, id, payload ->
      ["{\"tag\":", JSON.value(tag), ",\"robot\":", JSON.value(id), ",\"payload\":"]
      |> Kernel.++([JSON.value(payload), ?}])
      |> IO.iodata_to_binary()
    end

    for _ <- 1..2_000 do
      {tag, id, payload} = {random_leaf(), random_leaf(), random_term(3)}
      assert Native.tuple(tag, id, payload) == erlang.(tag, id, payload)
    end

    assert Native.tuple(:odom, :r1, %{stamp: 1.5}) ==
             ~s({"tag":"odom","robot":"r1","payload":{"stamp":1.5}})

    assert Native.tuple(:odom, :rö, 1) == false
    assert Native.tuple(:odom, :r1, [1 | 2]) == false
  end

  test "integers at int64's ends" do
    for i <- [-9_223_372_036_854_775_808, 9_223_372_036_854_775_807, -1, 0, 10, -10] do
      assert Native.value(i) == Integer.to_string(i)
      assert Native.millimetres([i]) == "[#{i}]"
    end
  end

  test "what C is not sure of is left to Core.JSON" do
    for term <- [
          123_456_789_012_345_678_901_234_567_890,
          "héllo",
          <<255, 0>>,
          [1 | 2],
          self(),
          Map.new(1..33, &{&1, &1}),
          %{{:k, 1} => 1}
        ] do
      assert Native.value(term) == false
      assert JSON.fast(term) |> IO.iodata_to_binary() == elixir(term)
    end
  end

  test "a scan's ranges to the millimetre, as float_to_binary writes them" do
    ranges = for _ <- 1..5_000, do: random_float()
    ranges = [3, 0 | ranges]

    expected =
      "[" <>
        Enum.map_join(ranges, ",", fn
          r when is_float(r) -> :erlang.float_to_binary(r, [{:decimals, 3}, :compact])
          r -> Integer.to_string(r)
        end) <> "]"

    assert Native.millimetres(ranges) == expected
    assert Native.millimetres([]) == "[]"
    assert_raise ArgumentError, fn -> Native.millimetres([1.0, :nan]) end
  end
end
