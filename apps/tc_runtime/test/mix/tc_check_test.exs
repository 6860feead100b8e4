defmodule Mix.Tasks.Tc.CheckTest do
  # Not async: `mix tc.check` runs `loadpaths`, which in an umbrella steps
  # the whole VM's working directory to the umbrella root and back, and the
  # Mix shell is global. Sync modules run only once every test file is
  # loaded, so no file is then being required by a relative path.
  use ExUnit.Case, async: false

  @examples Path.expand("../../../../priv/examples", __DIR__)

  @moduletag :tmp_dir

  setup do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
  end

  test "accepts the examples" do
    files = for f <- ~w(office.adf office_robot.rdf office.wdf), do: Path.join(@examples, f)
    Mix.Tasks.Tc.Check.run(files)
    assert_received {:mix_shell, :info, ["3 file(s) OK"]}
  end

  test "prints every error and fails", %{tmp_dir: dir} do
    bad = Path.join(dir, "bad.wdf")
    File.write!(bad, "[name: :not_a_string, walls: 3]")
    good = Path.join(@examples, "office.wdf")

    assert_raise Mix.Error, "2 error(s) in description files", fn ->
      Mix.Tasks.Tc.Check.run([good, bad])
    end

    assert_received {:mix_shell, :error, [output]}
    assert output =~ "bad.wdf:1:8: name: expected a string, got :not_a_string"
    assert output =~ "bad.wdf:1:30: walls: expected a list, got 3"
  end

  test "refuses to run without files" do
    assert_raise Mix.Error, "usage: mix tc.check FILE... | mix tc.check --explain MODULE", fn ->
      Mix.Tasks.Tc.Check.run([])
    end
  end

  defmodule Cruise do
    @moduledoc false
    def params, do: [speed: {{:number_range, 0.0, 1.0}, default: 0.3, doc: "m/s"}]
  end

  test "--explain prints the params a module declares, and refuses one that declares none" do
    Mix.Tasks.Tc.Check.run(["--explain", inspect(Cruise)])
    assert_received {:mix_shell, :info, [output]}
    assert output =~ "| `speed` | number 0.0..1.0 | `0.3` | m/s |"

    assert_raise Mix.Error, ~r/String declares no params/, fn ->
      Mix.Tasks.Tc.Check.run(["--explain", "String"])
    end
  end
end
