defmodule ThinkingCap.Navigation.DeclaredParamsTest do
  # A module's declared params (ThinkingCap.Module.params/0) checked when
  # the ADF is read: on a copy of the example files, a misspelt key, a
  # value out of range and a waypoint the WDF lacks are each refused at
  # their file:line.
  use ExUnit.Case, async: true

  alias ThinkingCap.Config
  alias ThinkingCap.Config.ADF

  @moduletag :tmp_dir
  @examples Path.expand("../../../../../priv/examples", __DIR__)

  @localizer "params: [initial: :dock, initial_sigma: {0.1, 0.05}]"
  @planner "params: [task: {:patrol, [:lab_bench, :desk_a, :hall_east, :dock]}]"

  # the example set copied, with a module's params line (the localizer's
  # unless told) replaced
  defp adf_with(dir, params_line, old \\ @localizer) do
    for f <- ~w(office_sim.adf office_robot.rdf office.wdf),
        do: File.cp!(Path.join(@examples, f), Path.join(dir, f))

    path = Path.join(dir, "office_sim.adf")
    source = File.read!(path)
    assert source =~ old
    File.write!(path, String.replace(source, old, params_line))
    line = source |> String.split("\n") |> Enum.find_index(&(&1 =~ old)) |> Kernel.+(1)
    {path, line}
  end

  test "the example set passes", %{tmp_dir: dir} do
    {path, _line} = adf_with(dir, "params: [initial: :dock, initial_sigma: {0.1, 0.05}]")
    assert {:ok, %ADF{}} = Config.read(path)
  end

  test "a misspelt param is refused with a did-you-mean at its line", %{tmp_dir: dir} do
    {path, line} = adf_with(dir, "params: [initial: :dock, sed: 3]")
    assert {:error, [error]} = Config.read(path)
    assert error.line == line
    assert error.message =~ "unknown key :sed"
    assert error.message =~ "did you mean :seed?"
  end

  test "a value out of range is refused with the range", %{tmp_dir: dir} do
    {path, line} = adf_with(dir, "params: [initial: :dock, particles: 3, z_hit: 1.5]")
    assert {:error, errors} = Config.read(path)
    assert Enum.all?(errors, &(&1.line == line))
    messages = Enum.map_join(errors, "\n", & &1.message)
    assert messages =~ "particles: expected an integer from 10 to 100000, got 3"
    assert messages =~ "z_hit: expected a probability from 0 to 1, got 1.5"
  end

  test "a waypoint the WDF lacks is refused, with the name it may mean", %{tmp_dir: dir} do
    {path, line} = adf_with(dir, "params: [initial: :dok]")
    assert {:error, [error]} = Config.read(path)
    assert error.line == line
    assert error.message =~ ":dok is not a waypoint, room, corridor or door of the WDF"
    assert error.message =~ "did you mean :dock?"
  end

  test "the planner's task and params are checked too", %{tmp_dir: dir} do
    {path, line} =
      adf_with(dir, "params: [task: {:patrol, [:lab_bench, :desk_c]}, tolerence: 0.3]", @planner)

    assert {:error, errors} = Config.read(path)
    assert Enum.all?(errors, &(&1.line == line))
    messages = Enum.map_join(errors, "\n", & &1.message)
    assert messages =~ "unknown key :tolerence"
    assert messages =~ "did you mean :tolerance?"
    assert messages =~ ":desk_c is not a waypoint, room, corridor or door of the WDF"
  end

  test "a task that is none of the planner's is refused", %{tmp_dir: dir} do
    {path, line} = adf_with(dir, "params: [task: {:goto, :dock}, max_replans: -1]", @planner)
    assert {:error, errors} = Config.read(path)
    assert Enum.all?(errors, &(&1.line == line))
    messages = Enum.map_join(errors, "\n", & &1.message)
    assert messages =~ "task"
    assert messages =~ "{:goto, :dock}"
    assert messages =~ "max_replans"
  end

  test "a module's schema is there to print" do
    fields = ADF.declared_params(ThinkingCap.Navigation.MCL)
    assert {:int_range, 10, 100_000} = elem(fields[:particles], 0)
    assert elem(fields[:particles], 1)[:default] == 500
    assert {:pos_number, opts} = fields[:sigma_hit]
    assert opts[:read_only] == true
    assert ADF.declared_params(String) == nil
  end
end
