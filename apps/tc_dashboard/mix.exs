# Debian's yaws lives outside OTP's library directory: put its ebin on the
# code path so the compiler (and `mix`) know its modules.
for ebin <- Path.wildcard("/usr/lib/yaws-*/ebin"), do: Code.prepend_path(ebin)

defmodule ThinkingCap.Dashboard.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_dashboard,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      # yaws is started by the dashboard itself, in embedded mode, when it
      # is wanted (not as a dependency application)
      xref: [exclude: [:yaws_api, :yaws]],
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      deps: [
        {:tc_cognition, in_umbrella: true},
        {:tc_sim, in_umbrella: true}
      ]
    ]
  end

  def application do
    [
      mod: {ThinkingCap.Dashboard.Application, []},
      extra_applications: [:logger, :crypto, :jiffy]
    ]
  end
end
