defmodule Mix.Tasks.Compile.TcTiming do
  @moduledoc false
  # Builds the C timing worker (c_src/tc_timing.c -> priv/bin/tc_timing)
  # with the system C compiler; no hex build tools. Defined here so that it
  # exists before the app it builds for is compiled.
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @app_dir __DIR__
  @source Path.join(__DIR__, "c_src/tc_timing.c")
  @target Path.join(__DIR__, "priv/bin/tc_timing")

  @impl true
  def run(_args) do
    if Mix.Utils.stale?([@source], [@target]) do
      File.mkdir_p!(Path.dirname(@target))
      cc = System.get_env("CC", "cc")
      args = ~w(-O2 -Wall -Wextra -Werror -pthread -o #{@target} #{@source})

      case System.cmd(cc, args, stderr_to_stdout: true) do
        {_, 0} ->
          Mix.shell().info("Compiled #{Path.relative_to(@target, @app_dir)}")
          {:ok, []}

        {output, status} ->
          Mix.shell().error(output)

          diagnostic = %Mix.Task.Compiler.Diagnostic{
            compiler_name: "tc_timing",
            file: @source,
            message: "#{cc} exited with #{status}",
            position: nil,
            severity: :error
          }

          {:error, [diagnostic]}
      end
    else
      {:noop, []}
    end
  end

  @impl true
  def clean, do: File.rm(@target)
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
    # fast_yaml: Debian's erlang-p1-yaml, for ROS map_server YAML files
    [extra_applications: [:logger, :fast_yaml], mod: {ThinkingCap.Runtime.Application, []}]
  end
end
