defmodule ThinkingCap.BlackBox.Core.JSON.NativeTest do
  use ExUnit.Case, async: true
  import Bitwise

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

  # terms as term_to_binary writes them in every form value/1 meets:
  # lists of bytes, big integers, large tuples, maps up to 32 keys and past
  defp etf_term(0), do: etf_leaf()

  defp etf_term(depth) do
    case :rand.uniform(9) do
      1 -> Enum.map(1..:rand.uniform(5), fn _ -> etf_term(depth - 1) end)
      2 -> List.to_tuple(Enum.map(1..:rand.uniform(4), fn _ -> etf_term(depth - 1) end))
      3 -> Map.new(1..:rand.uniform(6), fn i -> {random_key(i), etf_term(depth - 1)} end)
      4 -> %URI{host: "h", port: :rand.uniform(100), path: etf_term(depth - 1)}
      5 -> Enum.to_list(0..:rand.uniform(300))
      6 -> Map.new(1..Enum.random([31, 32, 33]), &{random_key(&1), etf_leaf()})
      7 -> %{__struct__: Enum.random(["s", :"not.an.Alias", :"Elixir", :"Elixir.A.b"]), a: 1}
      8 -> List.to_tuple(Enum.to_list(1..Enum.random([255, 256, 300])))
      _ -> etf_leaf()
    end
  end

  # now and then one value/1 leaves to Erlang
  defp etf_leaf do
    case :rand.uniform(20) do
      1 -> Enum.random(["héllo", :rö, <<1::3>>, [1 | 2], self(), make_ref(), &Enum.map/2])
      2 -> Enum.random([255, 256, -256, 2_147_483_647, 2_147_483_648, -2_147_483_649])
      3 -> Enum.random([1 <<< 59, -9_223_372_036_854_775_808, (1 <<< 63) - 1, 1 <<< 63])
      _ -> random_leaf()
    end
  end

  defp tuple_json(tag, id, payload),
    do: ThinkingCap.BlackBox.Foxglove.generic_json(tag, id, payload) |> IO.iodata_to_binary()

  test "a thinkingcap.Tuple message from the tuple's external term, as Core.JSON writes it" do
    written =
      for _ <- 1..3_000, reduce: 0 do
        n ->
          {tag, id, payload} = {etf_leaf(), etf_leaf(), etf_term(3)}

          case Native.tuple_etf(:erlang.term_to_binary({tag, id, payload})) do
            false ->
              assert Native.tuple(tag, id, payload) == false
              n

            json ->
              assert json == tuple_json(tag, id, payload)
              n + 1
          end
      end

    # most of them in C
    assert written > 1_000

    etf = :erlang.term_to_binary({:odom, :r1, %{stamp: 1.5, v: [1, 2]}})

    assert Native.tuple_etf(etf) ==
             ~s({"tag":"odom","robot":"r1","payload":{"v":[1,2],"stamp":1.5}})
  end

  test "an external term that is not a 3-tuple, or is cut short, is left to Erlang" do
    assert Native.tuple_etf(:erlang.term_to_binary({:a, :b})) == false
    assert Native.tuple_etf(:erlang.term_to_binary([:a, :b, :c])) == false

    assert Native.tuple_etf(:erlang.term_to_binary({:a, :b, :c}, [:compressed])) in [
             false,
             "{\"tag\":\"a\",\"robot\":\"b\",\"payload\":\"c\"}"
           ]

    assert Native.tuple_etf("") == false
    assert_raise ArgumentError, fn -> Native.tuple_etf(:not_a_binary) end

    for _ <- 1..300 do
      etf = :erlang.term_to_binary({:odom, :r1, etf_term(3)})
      cut = binary_part(etf, 0, :rand.uniform(byte_size(etf)) - 1)
      assert Native.tuple_etf(cut) == false
      assert Native.tuple_etf(etf <> <<0>>) == false
    end
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
