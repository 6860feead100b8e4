defmodule ThinkingCap.Robot.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_robot,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      deps: [{:tc_runtime, in_umbrella: true}]
    ]
  end

  def application do
    # xmerl: URDF files are XML
    [extra_applications: [:logger, :xmerl]]
  end
end
