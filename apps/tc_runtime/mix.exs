defmodule ThinkingCap.Runtime.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_runtime,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      deps: [{:tc_blackboard, in_umbrella: true}]
    ]
  end

  def application do
    # fast_yaml: Debian's erlang-p1-yaml, for ROS map_server YAML files
    [extra_applications: [:logger, :fast_yaml]]
  end
end
