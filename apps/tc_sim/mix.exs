defmodule Mix.Tasks.Compile.TcRaycast do
  @moduledoc false
  # Builds the ray-casting NIF (c_src/tc_raycast.c -> priv/lib/tc_raycast.so)
  # with the system C compiler; no hex build tools. Defined here so that it
  # exists before the app it builds for is compiled.
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @app_dir __DIR__
  @sources [Path.join(__DIR__, "c_src/tc_raycast.c")]
  @target Path.join(__DIR__, "priv/lib/tc_raycast.so")

  @impl true
  def run(_args) do
    sources = @sources ++ Path.wildcard(Path.join(@app_dir, "c_src/*.h"))

    if Mix.Utils.stale?(sources, [@target]) do
      File.mkdir_p!(Path.dirname(@target))
      cc = System.get_env("CC", "cc")

      args =
        ~w(-O2 -Wall -Wextra -Werror -fPIC -shared -I#{erts_include()} -o #{@target}) ++
          @sources ++ ["-lm"]

      case System.cmd(cc, args, stderr_to_stdout: true) do
        {_, 0} ->
          Mix.shell().info("Compiled #{Path.relative_to(@target, @app_dir)}")
          link_priv()
          {:ok, []}

        {output, status} ->
          Mix.shell().error(output)

          diagnostic = %Mix.Task.Compiler.Diagnostic{
            compiler_name: "tc_raycast",
            file: hd(@sources),
            message: "#{cc} exited with #{status}",
            position: nil,
            severity: :error
          }

          {:error, [diagnostic]}
      end
    else
      link_priv()
      {:noop, []}
    end
  end

  @impl true
  def clean, do: File.rm(@target)

  defp erts_include do
    dir = Path.join([:code.root_dir(), "erts-#{:erlang.system_info(:version)}", "include"])
    if File.exists?(Path.join(dir, "erl_nif.h")), do: dir, else: "/usr/lib/erlang/usr/include"
  end

  # Mix links priv/ into the build directory before the compilers run; on a
  # fresh checkout priv/ only exists once this compiler has run, so link it.
  defp link_priv do
    unless File.exists?(Path.join(Mix.Project.app_path(), "priv")) do
      Mix.Project.build_structure()
    end
  end
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
