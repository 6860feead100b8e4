Code.require_file("../../mix/c_build.exs", __DIR__)

defmodule Mix.Tasks.Compile.TcTiming do
  @moduledoc false
  # Builds the C timing worker (c_src/tc_timing.c -> priv/bin/tc_timing).
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @target "priv/bin/tc_timing"

  @impl true
  def run(_args),
    do:
      ThinkingCap.Build.C.compile("tc_timing", __DIR__, ["c_src/tc_timing.c"], @target,
        cflags: ["-pthread"]
      )

  @impl true
  def clean, do: File.rm(Path.join(__DIR__, @target))
end

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
      compilers: [:tc_timing | Mix.compilers()],
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      deps: [{:tc_blackboard, in_umbrella: true}]
    ]
  end

  def application do
    [extra_applications: [:logger], mod: {ThinkingCap.Runtime.Application, []}]
  end
end
