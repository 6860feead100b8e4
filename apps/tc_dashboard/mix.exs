# Debian's yaws lives outside OTP's library directory (/usr/lib/yaws-*).
# A copy of it under _build/vendor goes on the code path, so the compiler,
# mix and the tests know its modules, and `mix release` takes it into the
# release (taken from /usr/lib, the release's boot script would get OTP's
# own paths wrong: /usr/lib would be their common root).
vendor = Path.expand("../../_build/vendor", __DIR__)

for source <- Path.wildcard("/usr/lib/yaws-*") do
  target = Path.join(vendor, Path.basename(source))

  unless File.exists?(Path.join(target, "ebin/yaws.app")) do
    partial = target <> ".partial"
    File.rm_rf!(partial)
    File.mkdir_p!(partial)

    for sub <- ["ebin", "priv", "include"],
        File.dir?(Path.join(source, sub)),
        do: File.cp_r!(Path.join(source, sub), Path.join(partial, sub))

    File.rm_rf!(target)
    File.rename!(partial, target)
  end

  Code.prepend_path(Path.join(target, "ebin"))
end

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
      # yaws runs embedded under the dashboard's own supervisor when it
      # is wanted (Core.WebServer), never as an application
      xref: [exclude: [:yaws_api, :yaws]],
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      deps: [
        {:tc_cognition, in_umbrella: true},
        {:tc_blackbox, in_umbrella: true},
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
