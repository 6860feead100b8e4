defmodule ThinkingCap.TuplesTest do
  use ExUnit.Case, async: true

  import ExUnit.CaptureIO

  alias ThinkingCap.Blackboard
  alias ThinkingCap.Blackboard.Template
  alias ThinkingCap.Tuples
  require Tuples

  defp matches?(template, tuple), do: template |> Template.compile() |> Template.matches?(tuple)

  # compiles a module whose body is `body`, with the vocabulary aliased
  defp compile(body) do
    name = "ThinkingCap.TuplesTest.Snippet#{System.unique_integer([:positive])}"

    Code.compile_string("""
    defmodule #{name} do
      alias ThinkingCap.Tuples
      require Tuples
      #{body}
    end
    """)
  end

  describe "a misspelt name does not compile" do
    test "in a pattern: a compile error" do
      error =
        assert_raise CompileError, fn ->
          compile("def f(Tuples.estp(robot, _)), do: robot")
        end

      assert error.description =~ "ThinkingCap.Tuples.estp/2"
    end

    test "imported: a compile error" do
      error =
        assert_raise CompileError, fn ->
          Code.compile_string("""
          defmodule ThinkingCap.TuplesTest.Imported do
            import ThinkingCap.Tuples, only: [estop: 2]
            def f(robot), do: estp(robot, %{engaged: true})
          end
          """)
        end

      assert error.description =~ "undefined function estp/2"
    end

    test "in an expression: the compiler reports it (an error under --warnings-as-errors)" do
      report = capture_io(:stderr, fn -> compile("def f(robot), do: Tuples.estp(robot)") end)
      assert report =~ "ThinkingCap.Tuples.estp/1 is undefined or private"
      assert report =~ "estop/1"
    end

    test "a tag named on its own: a compile error" do
      assert_raise CompileError, ~r/:estp is not a tag/, fn ->
        compile("@streams [Tuples.tag(:pose), Tuples.tag(:estp)]\ndef s, do: @streams")
      end

      assert Tuples.tag(:estop) == :estop
    end

    test "a template used as a pattern: a compile error saying to give the payload" do
      assert_raise CompileError, ~r/not a pattern: give the payload/, fn ->
        compile("def f(Tuples.estop(robot)), do: robot")
      end
    end
  end

  describe "constructors and templates" do
    for tag <- Tuples.tags() do
      test "#{inspect(tag)}: the tuple matches its templates, and the constructor as a pattern" do
        # the robot at run time: the compiler would see through literals
        r1 = String.to_atom("r1")
        tuple = Tuples.unquote(tag)(r1, %{n: 1})
        assert tuple == {unquote(tag), :r1, %{n: 1}}

        assert Tuples.unquote(tag)(:r1) == {unquote(tag), :r1, :_}
        assert Tuples.unquote(tag)() == {unquote(tag), :_, :_}
        assert matches?(Tuples.unquote(tag)(:r1), tuple)
        assert matches?(Tuples.unquote(tag)(), tuple)
        refute matches?(Tuples.unquote(tag)(:r2), tuple)
        refute matches?(Tuples.unquote(tag)(:r1), {:other, :r1, %{n: 1}})

        assert Tuples.unquote(tag)(robot, %{n: n}) = tuple
        assert {robot, n} == {:r1, 1}
      end
    end

    test "readings: tagged with the sensor's name" do
      scan = Tuples.reading(:laser, :r1, %{ranges: [1.0]})
      assert scan == {:laser, :r1, %{ranges: [1.0]}}
      assert matches?(Tuples.reading(:laser, :r1), scan)
      assert matches?(Tuples.reading(:laser), scan)
      refute matches?(Tuples.reading(:sonar, :r1), scan)
      assert Tuples.reading(sensor, :r1, %{ranges: [_]}) = scan
      assert sensor == :laser
    end

    test "the tags are those the macros are named after, one each" do
      tags = Tuples.tags()
      assert tags == Enum.uniq(tags)
      for tag <- tags, arity <- 0..2, do: assert(macro_exported?(Tuples, tag, arity))
    end
  end

  describe "E-stops and keys" do
    test "an engaged and a released E-stop, the one way" do
      assert Tuples.estop_engaged(:r1, :console, 5) ==
               {:estop, :r1, %{engaged: true, by: :console, at: 5}}

      assert Tuples.estop(:r1, %{engaged: true, at: at}) = Tuples.estop_engaged(:r1, "me")
      assert is_integer(at)

      assert Tuples.estop(:r1, %{engaged: false, by: :console}) =
               Tuples.estop_released(:r1, :console)
    end

    test "keys: {tag, id}, per module and param, per module, per node" do
      assert Tuples.key(Tuples.estop_engaged(:r1, :me)) == {:estop, :r1}
      assert Tuples.key(Tuples.timing(:base, %{})) == {:timing, :base}
      assert Tuples.key(Tuples.reading(:laser, :r1, %{})) == {:laser, :r1}

      assert Tuples.key(Tuples.param(:r1, %{module: :m, key: :k, value: 1})) ==
               {:param, :r1, :m, :k}

      assert Tuples.key(Tuples.module_gave_up(:r1, %{module: :m})) == {:module_gave_up, :r1, :m}
      assert Tuples.key(Tuples.cluster(:r1, %{node: :n@h})) == {:cluster, :r1, :n@h}

      assert Tuples.keyed(Tuples.drive(:r1, %{command: :stop})) ==
               {{:drive, :r1, %{command: :stop}}, [key: {:drive, :r1}]}
    end

    test "on the blackboard: written keyed, read and subscribed to by template" do
      robot = :"tuples_test_#{System.unique_integer([:positive])}"
      {:ok, ref} = Blackboard.subscribe(Tuples.estop(robot))

      {tuple, opts} = Tuples.keyed(Tuples.estop_engaged(robot, :test))
      :ok = Blackboard.out(tuple, opts)
      assert_receive {:blackboard, ^ref, Tuples.estop(^robot, %{engaged: true})}

      {tuple, opts} = Tuples.keyed(Tuples.estop_released(robot, :test))
      :ok = Blackboard.out(tuple, opts)
      assert_receive {:blackboard, ^ref, Tuples.estop(^robot, %{engaged: false})}

      # the latest only, whoever wrote it
      assert [Tuples.estop(^robot, %{engaged: false, by: :test})] =
               Blackboard.rd_all(Tuples.estop(robot))

      Blackboard.unsubscribe(ref)
      {:ok, _} = Blackboard.takep(Tuples.estop(robot))
    end
  end
end
