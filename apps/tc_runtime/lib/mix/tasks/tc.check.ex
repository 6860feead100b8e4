defmodule Mix.Tasks.Tc.Check do
  @shortdoc "Validates ADF/RDF/WDF description files"
  @moduledoc """
  Validates any mix of description files and prints every error as
  `file:line:column: message`; exits non-zero if there is any.

      mix tc.check priv/examples/office.adf priv/examples/office_robot.rdf priv/examples/office.wdf
  """
  use Mix.Task

  @impl true
  def run([]), do: Mix.raise("usage: mix tc.check FILE...")

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
