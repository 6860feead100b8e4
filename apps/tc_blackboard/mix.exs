defmodule ThinkingCap.Blackboard.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_blackboard,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_paths: elixirc_paths(Mix.env()),
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      deps: []
    ]
  end

  def application do
    [
      extra_applications: [:logger],
      # Debian's erlang-proper and erlang-redis-client are used by the tests
      # and the benchmark only; they are on the code path, not started here.
      mod: {ThinkingCap.Blackboard.Application, []}
    ]
  end

  defp elixirc_paths(:test), do: ["lib", "test/support"]
  defp elixirc_paths(_), do: ["lib"]
end
