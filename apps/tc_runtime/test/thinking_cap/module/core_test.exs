defmodule ThinkingCap.Module.CoreTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Module.ActionError
  alias ThinkingCap.Module.Core.{Actions, Params}
  alias ThinkingCap.Test.Modules

  describe "Actions.interpret/4" do
    test "actions become effects, in order; a keyword list is a list of actions" do
      assert {:ok, effects, :s} =
               Actions.interpret(
                 {[
                    out: {:a, :r, 1},
                    out: {{:b, :r, 2}, [key: :b]},
                    subscribe: {:c, :_, :_}
                  ], :s},
                 M,
                 :handle_tuple,
                 :event
               )

      assert effects == [
               {:out, {:a, :r, 1}, []},
               {:out, {:b, :r, 2}, [key: :b]},
               {:subscribe, {:c, :_, :_}}
             ]
    end

    test "handle_cycle's result comes first: the last command and the last wire" do
      assert {:ok, [{:cycle_result, {:go, 2}, "2\n"}, {:out, {:x, :r, 1}, []}], nil} =
               Actions.interpret(
                 {[
                    command: {:go, 1},
                    wire: "1\n",
                    out: {:x, :r, 1},
                    command: {:go, 2},
                    wire: "2\n"
                  ], nil},
                 M,
                 :handle_cycle,
                 :periodic
               )

      assert {:ok, [{:cycle_result, nil, nil}], nil} =
               Actions.interpret({[], nil}, M, :handle_cycle, :periodic)
    end

    test "a command outside handle_cycle and a wire of a module that is not periodic are warnings" do
      assert {:ok, [{:warning, w1}, {:attach_wire, "/dev/null", "s"}, :detach_wire], nil} =
               Actions.interpret(
                 {[{:command, :x}, {:attach_wire, "/dev/null", "s"}, {:detach_wire}], nil},
                 M,
                 :handle_tuple,
                 :periodic
               )

      assert w1 == "a :command action only counts in handle_cycle/2"

      assert {:ok, [{:warning, w}], nil} =
               Actions.interpret(
                 {[{:attach_wire, "/dev/ttyS0", "s"}], nil},
                 M,
                 :handle_tuple,
                 :event
               )

      assert w =~ "needs a periodic activity"
    end

    test "an unknown action is an error naming the module, the callback and the known actions" do
      assert {:error, %ActionError{module: MyMod, callback: :handle_cycle} = e} =
               Actions.interpret({[{:outt, {:x, :r, 1}}], nil}, MyMod, :handle_cycle, :periodic)

      assert e.message =~ "MyMod.handle_cycle/2 returned an unknown action {:outt, {:x, :r, 1}}"
      assert e.message =~ "known: {:out, tuple}"
    end

    test "a malformed action says what is wrong with it" do
      assert {:error, %ActionError{message: m}} =
               Actions.interpret({[out: 42], nil}, MyMod, :handle_tuple, :event)

      assert m ==
               "MyMod.handle_tuple/2 returned a malformed action {:out, 42}: :out takes a tuple, or {tuple, opts}"

      assert {:error, %ActionError{message: m}} =
               Actions.interpret({[wire: :nope], nil}, MyMod, :handle_cycle, :periodic)

      assert m =~ ":wire takes iodata"
    end

    test "a result that is not {actions, state} is an error naming the callback" do
      assert {:error, %ActionError{message: m}} =
               Actions.interpret(:ok, MyMod, :handle_background, :background)

      assert m == "MyMod.handle_background/1 must return {actions, state}, got: :ok"

      assert {:ok, [], :s} = Actions.interpret({:ok, :s}, MyMod, :init, :event)
      assert {:error, _} = Actions.interpret({:ok, :s}, MyMod, :handle_tuple, :event)
    end
  end

  describe "Params" do
    test "declared fields start from their defaults and the ADF's values" do
      params = Params.init(Modules.Tunable, speed: 0.5)
      assert params.values == %{speed: 0.5, gain: 1.0, mode: :slow, enabled: true, seed: 1}
      assert params.live
      refute Params.init(Modules.Declared, []).live
      assert Params.init(Modules.Cruise, %{speed: 0.1}).values == %{speed: 0.1}
    end

    test "a change is checked: range, type, choice, read-only, unknown key, live" do
      p = Params.init(Modules.Tunable, [])
      assert {:ok, 0.4} = Params.check(p, Modules.Tunable, :speed, 0.4)
      assert {:ok, 1.0} = Params.check(p, Modules.Tunable, :speed, 1)

      assert {:error, "speed: expected a number from 0.0 to 1.0, got 5"} =
               Params.check(p, Modules.Tunable, :speed, 5)

      assert {:error, "enabled: expected true or false, got \"yes\""} =
               Params.check(p, Modules.Tunable, :enabled, "yes")

      assert {:error, "mode: expected one of :slow, :fast, got :medium"} =
               Params.check(p, Modules.Tunable, :mode, :medium)

      # a number too large to be a float is refused, not crashed on
      assert {:error, "gain: " <> _} = Params.check(p, Modules.Tunable, :gain, 10 ** 400)

      assert {:error, m} = Params.check(p, Modules.Tunable, :seed, 2)
      assert m =~ "seed of ThinkingCap.Test.Modules.Tunable is read-only"

      assert {:error, m} = Params.check(p, Modules.Tunable, :sped, 0.1)
      assert m =~ "has no param :sped; did you mean :speed?"

      assert {:error, m} =
               Params.check(Params.init(Modules.Declared, []), Modules.Declared, :speed, 0.1)

      assert m =~ "takes no live changes"

      assert {:error, m} =
               Params.check(Params.init(Modules.Cruise, []), Modules.Cruise, :speed, 0.1)

      assert m =~ "declares no params"
    end

    test "describe/1 gives each field's input, bounds and read-only flag" do
      fields = Params.describe(Params.init(Modules.Tunable, speed: 0.3))
      by_key = Map.new(fields, &{&1.key, &1})
      assert %{input: :number, min: 0.0, max: 1.0, value: 0.3, read_only: false} = by_key.speed
      assert %{input: :choice, choices: [:slow, :fast]} = by_key.mode
      assert %{input: :boolean} = by_key.enabled
      assert %{input: :integer, read_only: true} = by_key.seed

      assert [%{read_only: true}] = Params.describe(Params.init(Modules.Declared, []))
    end
  end
end
