Code.require_file("../../mix/c_build.exs", __DIR__)

defmodule Mix.Tasks.Compile.TcUart do
  @moduledoc false
  # Builds the serial line worker (c_src/tc_uart.c -> priv/bin/tc_uart).
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @target "priv/bin/tc_uart"

  @impl true
  def run(_args),
    do: ThinkingCap.Build.C.compile("tc_uart", __DIR__, ["c_src/tc_uart.c"], @target)

  @impl true
  def clean, do: File.rm(Path.join(__DIR__, @target))
end

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
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      compilers: [:tc_uart | Mix.compilers()],
      deps: [{:tc_runtime, in_umbrella: true}]
    ]
  end

  def application do
    # xmerl: URDF files are XML
    [extra_applications: [:logger, :xmerl]]
  end
end
