defmodule Mix.Tasks.Tc.Check do
  @shortdoc "Validates description files (ADF/RDF/WDF), ROS maps and URDFs"
  @moduledoc """
  Validates any mix of description files (`.adf`, `.rdf`, `.wdf`), ROS
  `map_server` maps (`.yaml`, with the PGM image they name) and URDF files
  (`.urdf`), and prints every error as `file:line:column: message` (or
  `file:byte OFFSET: message` in a PGM image), at most 50 per file and
  then how many more; exits non-zero if there is any. Each kind is read
  within bounds of size, depth and atoms (see the README).

      mix tc.check priv/examples/office.adf priv/examples/office_robot.rdf priv/examples/office.wdf
      mix tc.check priv/maps/office.yaml test/data/turtlebot3_burger.urdf

  A module's params are checked against the schema it declares
  (`c:ThinkingCap.Module.params/0`); `--explain MODULE` prints that schema:

      mix tc.check --explain ThinkingCap.Navigation.MCL
  """
  use Mix.Task

  alias ThinkingCap.Config.{ADF, Schema}

  @impl true
  def run(["--explain", name]) do
    Mix.Task.run("loadpaths")
    module = Module.concat([name])

    case ADF.declared_params(module) do
      nil ->
        Mix.raise("#{inspect(module)} declares no params (no params/0), or is not a module here")

      fields ->
        Mix.shell().info("params of #{inspect(module)}:\n\n" <> Schema.describe(fields))
    end
  end

  def run([]), do: Mix.raise("usage: mix tc.check FILE... | mix tc.check --explain MODULE")

  def run(paths) do
    Mix.Task.run("loadpaths")

    case ThinkingCap.Config.check(paths, readers()) do
      [] ->
        Mix.shell().info("#{length(paths)} file(s) OK")

      errors ->
        Mix.shell().error(ThinkingCap.Config.format_errors(errors))
        Mix.raise("#{length(errors)} error(s) in description files")
    end
  end

  # URDF files are read by tc_robot, a layer above tc_runtime: named, not
  # depended on, so tc_runtime alone still builds
  @urdf ThinkingCap.Robot.URDF

  defp readers do
    if Code.ensure_loaded?(@urdf) and function_exported?(@urdf, :load, 1),
      do: %{".urdf" => fn path -> apply(@urdf, :load, [path]) end},
      else: %{".urdf" => &no_urdf_reader/1}
  end

  defp no_urdf_reader(path),
    do:
      {:error,
       [
         ThinkingCap.Config.Error.new(
           path,
           {0, 0},
           "no URDF reader here: run mix tc.check from the umbrella's root (tc_robot reads URDFs)"
         )
       ]}
end
