defmodule Mix.Tasks.Tc.Check do
  @shortdoc "Validates ADF/RDF/WDF description files"
  @moduledoc """
  Validates any mix of description files and prints every error as
  `file:line:column: message`; exits non-zero if there is any.

      mix tc.check priv/examples/office.adf priv/examples/office_robot.rdf priv/examples/office.wdf

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

    case ThinkingCap.Config.check(paths) do
      [] ->
        Mix.shell().info("#{length(paths)} description file(s) OK")

      errors ->
        Mix.shell().error(ThinkingCap.Config.format_errors(errors))
        Mix.raise("#{length(errors)} error(s) in description files")
    end
  end
end
