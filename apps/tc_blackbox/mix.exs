Code.require_file("../../mix/c_build.exs", __DIR__)

defmodule Mix.Tasks.Compile.TcMcap do
  @moduledoc false
  # Builds the MCAP compression NIF (c_src/tc_mcap.c -> priv/lib/tc_mcap.so),
  # linked to Debian's libzstd, liblz4 and zlib (its CRC-32), and the
  # recorder's JSON NIF (c_src/tc_json.c -> priv/lib/tc_json.so).
  use Mix.Task.Compiler

  # run inside the app's project (cwd), not the umbrella's
  @recursive true
  @target "priv/lib/tc_mcap.so"
  # the recorder's JSON in C (c_src/tc_json.c)
  @json_target "priv/lib/tc_json.so"

  @impl true
  def run(_args) do
    with {status, _} = result when status != :error <-
           ThinkingCap.Build.C.compile("tc_mcap", __DIR__, ["c_src/tc_mcap.c"], @target,
             nif: true,
             ldflags: ["-lzstd", "-llz4", "-lz"]
           ),
         {json, _} when json != :error <-
           ThinkingCap.Build.C.compile("tc_json", __DIR__, ["c_src/tc_json.c"], @json_target,
             nif: true,
             ldflags: ["-lm"]
           ) do
      if status == :ok or json == :ok, do: {:ok, []}, else: result
    else
      error -> error
    end
  end

  @impl true
  def clean do
    File.rm(Path.join(__DIR__, @target))
    File.rm(Path.join(__DIR__, @json_target))
  end
end

defmodule ThinkingCap.BlackBox.MixProject do
  use Mix.Project

  def project do
    [
      app: :tc_blackbox,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_options: [warnings_as_errors: true],
      start_permanent: Mix.env() == :prod,
      compilers: [:tc_mcap | Mix.compilers()],
      elixirc_paths: if(Mix.env() == :test, do: ["lib", "test/support"], else: ["lib"]),
      # the simulator only for the tests that record a whole robot
      deps: [{:tc_cognition, in_umbrella: true}, {:tc_sim, in_umbrella: true, only: :test}]
    ]
  end

  def application do
    # jiffy: Debian's JSON NIF, the recorder's message encoder
    [
      mod: {ThinkingCap.BlackBox.Application, []},
      extra_applications: [:logger, :jiffy]
    ]
  end
end
