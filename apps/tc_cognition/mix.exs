Code.require_file("../../mix/c_build.exs", __DIR__)

defmodule Mix.Tasks.Compile.TcGrid do
  @moduledoc false
  # Builds the navigation grid NIF (c_src/tc_grid.c, tc_plan.c and
  # tc_mcl.c, tc_slam.c, tc_edt.c -> priv/lib/tc_grid.so).
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @target "priv/lib/tc_grid.so"

  @impl true
  def run(_args) do
    ThinkingCap.Build.C.compile(
      "tc_grid",
      __DIR__,
      [
        "c_src/tc_grid.c",
        "c_src/tc_plan.c",
        "c_src/tc_mcl.c",
        "c_src/tc_slam.c",
        "c_src/tc_edt.c"
      ],
      @target,
      nif: true,
      ldflags: ["-lm"]
    )
  end

  @impl true
  def clean, do: File.rm(Path.join(__DIR__, @target))
end

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
      compilers: [:tc_grid | Mix.compilers()],
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      # the simulator only for the tests that drive a whole robot
      deps: [{:tc_robot, in_umbrella: true}, {:tc_sim, in_umbrella: true, only: :test}]
    ]
  end

  def application do
    [extra_applications: [:logger]]
  end
end
