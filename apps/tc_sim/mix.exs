defmodule ThinkingCap.Sim.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_sim,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      deps: [{:tc_robot, in_umbrella: true}]
    ]
  end

  def application do
    [extra_applications: [:logger]]
  end
end
