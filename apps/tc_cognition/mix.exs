defmodule ThinkingCap.Cognition.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_cognition,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      # the simulator only for the tests that drive a whole robot
      deps: [{:tc_robot, in_umbrella: true}, {:tc_sim, in_umbrella: true, only: :test}]
    ]
  end

  def application do
    [extra_applications: [:logger]]
  end
end
