defmodule ThinkingCap.Control.FuzzyTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Control.Fuzzy
  alias ThinkingCap.Control.Fuzzy.Set

  doctest Fuzzy

  describe "membership functions" do
    test "triangle: 0 at its feet, 1 at its peak, linear between" do
      mf = {:triangle, 1.0, 2.0, 4.0}
      assert Fuzzy.membership(mf, 0.0) == 0.0
      assert Fuzzy.membership(mf, 1.0) == 0.0
      assert Fuzzy.membership(mf, 1.5) == 0.5
      assert Fuzzy.membership(mf, 2.0) == 1.0
      assert Fuzzy.membership(mf, 3.5) == 0.25
      assert Fuzzy.membership(mf, 4.0) == 0.0
      assert Fuzzy.membership(mf, 9.0) == 0.0
    end

    test "trapezoid: a plateau between b and c; vertical sides allowed" do
      mf = {:trapezoid, 0, 1, 3, 5}
      assert Fuzzy.membership(mf, 0.5) == 0.5
      assert Fuzzy.membership(mf, 1) == 1.0
      assert Fuzzy.membership(mf, 2) == 1.0
      assert Fuzzy.membership(mf, 3) == 1.0
      assert Fuzzy.membership(mf, 4) == 0.5
      assert Fuzzy.membership(mf, 5.5) == 0.0

      vertical = {:trapezoid, 1, 1, 2, 2}
      assert Fuzzy.membership(vertical, 0.99) == 0.0
      assert Fuzzy.membership(vertical, 1) == 1.0
      assert Fuzzy.membership(vertical, 2) == 1.0
      assert Fuzzy.membership(vertical, 2.01) == 0.0
    end

    test "shoulders: open to the left and to the right" do
      assert Fuzzy.membership({:left_shoulder, 1, 3}, -100) == 1.0
      assert Fuzzy.membership({:left_shoulder, 1, 3}, 2) == 0.5
      assert Fuzzy.membership({:left_shoulder, 1, 3}, 3) == 0.0
      assert Fuzzy.membership({:right_shoulder, 1, 3}, 1) == 0.0
      assert Fuzzy.membership({:right_shoulder, 1, 3}, 2.5) == 0.75
      assert Fuzzy.membership({:right_shoulder, 1, 3}, 100) == 1.0
    end

    test "singleton: 1 only at its point" do
      assert Fuzzy.membership({:singleton, 2.0}, 2.0) == 1.0
      assert Fuzzy.membership({:singleton, 2.0}, 2.001) == 0.0
    end

    test "variables refuse malformed and out-of-order membership functions and empty universes" do
      assert_raise ArgumentError, ~r/out of order/, fn ->
        Fuzzy.variable(:x, {0, 1}, bad: {:triangle, 0.5, 0.2, 0.9})
      end

      assert_raise ArgumentError, ~r/not a membership function/, fn ->
        Fuzzy.variable(:x, {0, 1}, bad: {:bell, 0.5, 0.2})
      end

      assert_raise ArgumentError, ~r/empty universe/, fn ->
        Fuzzy.variable(:x, {1, 1}, [])
      end
    end
  end

  describe "operators" do
    setup do
      vars = [
        Fuzzy.variable(:a, {0, 1}, high: {:right_shoulder, 0, 1}),
        Fuzzy.variable(:b, {0, 1}, high: {:right_shoulder, 0, 1})
      ]

      %{vars: vars, inputs: %{a: 0.3, b: 0.8}}
    end

    test "AND is min, OR is max, NOT is 1 - x", %{vars: vars, inputs: inputs} do
      a = {:is, :a, :high}
      b = {:is, :b, :high}
      assert Fuzzy.truth(a, inputs, vars) == 0.3
      assert Fuzzy.truth({:and, [a, b]}, inputs, vars) == 0.3
      assert Fuzzy.truth({:or, [a, b]}, inputs, vars) == 0.8
      assert_in_delta Fuzzy.truth({:not, a}, inputs, vars), 0.7, 1.0e-12
      assert_in_delta Fuzzy.truth({:and, [{:not, a}, b]}, inputs, vars), 0.7, 1.0e-12
    end

    test "constants and empty connectives", %{vars: vars, inputs: inputs} do
      assert Fuzzy.truth(true, inputs, vars) == 1.0
      assert Fuzzy.truth(false, inputs, vars) == 0.0
      assert Fuzzy.truth({:and, []}, inputs, vars) == 1.0
      assert Fuzzy.truth({:or, []}, inputs, vars) == 0.0
    end

    test "crisp inputs are clamped to the universe", %{vars: vars} do
      assert Fuzzy.truth({:is, :a, :high}, %{a: 7.0}, vars) == 1.0
      assert Fuzzy.truth({:is, :a, :high}, %{a: -7.0}, vars) == 0.0
    end

    test "unknown variables, terms and missing inputs are named", %{vars: vars} do
      assert_raise ArgumentError, ~r/unknown variable :c/, fn ->
        Fuzzy.truth({:is, :c, :high}, %{c: 1}, vars)
      end

      assert_raise ArgumentError, ~r/unknown term :low of :a/, fn ->
        Fuzzy.truth({:is, :a, :low}, %{a: 1}, vars)
      end

      assert_raise ArgumentError, ~r/no crisp input for :b/, fn ->
        Fuzzy.truth({:is, :b, :high}, %{a: 1}, vars)
      end
    end
  end

  describe "inference" do
    setup do
      vars = [
        # at x = 0.25: low = 1, high = 0.5
        Fuzzy.variable(:x, {0, 1},
          low: {:left_shoulder, 0.5, 1.0},
          high: {:right_shoulder, 0, 0.5}
        ),
        Fuzzy.variable(:y, {0, 10},
          left: {:triangle, 0, 2, 4},
          right: {:triangle, 6, 8, 10},
          mid: {:triangle, 3, 5, 7},
          point: {:singleton, 7.02}
        )
      ]

      %{vars: vars}
    end

    test "two rules: the centroid of two clipped triangles, as computed by hand", %{vars: vars} do
      rules = [
        [if: {:is, :x, :low}, then: [y: :left]],
        [if: {:is, :x, :high}, then: [y: :right]]
      ]

      %{y: set} = Fuzzy.evaluate(rules, %{x: 0.25}, vars)
      assert %Set{universe: {0.0, 10.0}} = set
      assert tuple_size(set.degrees) == 101

      # left: triangle of half-width 2 at full height, area 2, centroid 2;
      # right: the same clipped at 0.5, area 2 * 0.5 * (2 - 0.5) = 1.5,
      # centroid 8 (symmetric). Centroid: (2 * 2 + 1.5 * 8) / 3.5.
      assert_in_delta Fuzzy.defuzzify(set), 16 / 3.5, 1.0e-9
      # implication by min: the right triangle is clipped, not scaled
      assert elem(set.degrees, 80) == 0.5
      assert elem(set.degrees, 75) == 0.5
      assert_in_delta elem(set.degrees, 65), 0.25, 1.0e-9
      assert elem(set.degrees, 20) == 1.0
    end

    test "aggregation is max where conclusions overlap", %{vars: vars} do
      rules = [
        [if: {:is, :x, :low}, then: [y: :left]],
        [if: {:is, :x, :low}, then: [y: :mid]]
      ]

      %{y: set} = Fuzzy.evaluate(rules, %{x: 0.0}, vars)
      # at y = 3.5: left gives 0.25, mid gives 0.25; at y = 3.2: 0.4 and 0.1
      assert_in_delta elem(set.degrees, 32), 0.4, 1.0e-9
      assert_in_delta elem(set.degrees, 35), 0.25, 1.0e-9
      assert_in_delta elem(set.degrees, 38), 0.4, 1.0e-9
      # symmetric around 3.5
      assert_in_delta Fuzzy.defuzzify(set), 3.5, 1.0e-9
    end

    test "a rule's weight scales its firing degree", %{vars: vars} do
      rules = [[if: {:is, :x, :low}, then: [y: :mid], weight: 0.3]]
      %{y: set} = Fuzzy.evaluate(rules, %{x: 0.0}, vars)
      assert_in_delta Fuzzy.height(set), 0.3, 1.0e-12
    end

    test "one rule at full strength: the centroid is the triangle's own", %{vars: vars} do
      rules = [[if: true, then: [y: :mid]]]
      assert_in_delta Fuzzy.defuzzify(Fuzzy.evaluate(rules, %{}, vars).y), 5.0, 1.0e-9
    end

    test "an output singleton lands on its nearest sample", %{vars: vars} do
      %{y: set} = Fuzzy.evaluate([[if: true, then: [y: :point]]], %{}, vars)
      assert Fuzzy.defuzzify(set) == 7.0
      assert set.degrees |> Tuple.to_list() |> Enum.count(&(&1 > 0)) == 1
    end

    test "the number of samples is an option", %{vars: vars} do
      %{y: set} = Fuzzy.evaluate([[if: true, then: [y: :mid]]], %{}, vars, samples: 11)
      assert tuple_size(set.degrees) == 11
      assert elem(set.degrees, 5) == 1.0
    end

    test "no rule fires: the output set is empty and has no centroid", %{vars: vars} do
      rules = [[if: {:is, :x, :high}, then: [y: :right]]]
      %{y: set} = Fuzzy.evaluate(rules, %{x: 0.0}, vars)
      assert Fuzzy.height(set) == 0.0
      assert Fuzzy.defuzzify(set) == nil
      assert Fuzzy.defuzzify(set, 0.0) == 0.0
      assert Fuzzy.defuzzify(Fuzzy.empty_set({-1, 1}), :none) == :none
    end

    test "malformed rules are refused; validate/2 checks without evaluating", %{vars: vars} do
      assert_raise ArgumentError, ~r/not a rule/, fn ->
        Fuzzy.evaluate([[when: true, then: [y: :mid]]], %{}, vars)
      end

      assert_raise ArgumentError, ~r/not a rule/, fn ->
        Fuzzy.evaluate([[if: true, then: [y: :mid], weight: 2]], %{}, vars)
      end

      assert :ok = Fuzzy.validate([[if: {:not, {:is, :x, :low}}, then: [y: :mid]]], vars)

      assert {:error, "unknown term :up of :y"} =
               Fuzzy.validate([[if: {:is, :x, :low}, then: [y: :up]]], vars)

      assert {:error, "not a condition: {:maybe, :x}"} =
               Fuzzy.validate([[if: {:or, [{:maybe, :x}]}, then: [y: :mid]]], vars)
    end
  end

  describe "sets" do
    test "clip and union" do
      a = %Set{universe: {0.0, 1.0}, degrees: {0.0, 0.5, 1.0}}
      b = %Set{universe: {0.0, 1.0}, degrees: {0.8, 0.2, 0.0}}
      assert Fuzzy.clip(a, 0.6).degrees == {0.0, 0.5, 0.6}
      assert Fuzzy.union([a, b]).degrees == {0.8, 0.5, 1.0}
      assert_in_delta Fuzzy.defuzzify(a), (0.5 * 0.5 + 1.0) / 1.5, 1.0e-12

      assert_raise ArgumentError, ~r/cannot join/, fn ->
        Fuzzy.union([a, %Set{universe: {0.0, 2.0}, degrees: {0.0, 0.0, 0.0}}])
      end
    end
  end
end
