Code.require_file("../../mix/c_build.exs", __DIR__)

defmodule Mix.Tasks.Compile.TcRaycast do
  @moduledoc false
  # Builds the ray-casting NIF (c_src/tc_raycast.c -> priv/lib/tc_raycast.so).
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @target "priv/lib/tc_raycast.so"

  @impl true
  def run(_args) do
    ThinkingCap.Build.C.compile("tc_raycast", __DIR__, ["c_src/tc_raycast.c"], @target,
      nif: true,
      ldflags: ["-lm"]
    )
  end

  @impl true
  def clean, do: File.rm(Path.join(__DIR__, @target))
end

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
      compilers: [:tc_raycast | Mix.compilers()],
      deps: [{:tc_robot, in_umbrella: true}]
    ]
  end

  def application do
    [extra_applications: [:logger], mod: {ThinkingCap.Sim.Application, []}]
  end
end
