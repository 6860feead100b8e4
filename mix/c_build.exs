defmodule ThinkingCap.Build.C do
  @moduledoc false
  # The C build step behind the apps' own Mix compilers (the timing worker,
  # the ray-casting NIF): the system C compiler, no hex build tools. Each
  # app's mix.exs requires this file and defines its compiler with it, so
  # the compiler exists before the app it builds for is compiled.

  # the headers every app's C code may include (tc_nif.h, tc_port.h)
  @shared Path.expand("../c_include", __DIR__)

  @doc """
  Builds `target` from the app's `sources` (paths relative to `app_dir`)
  when a source or a header in `c_src/` or the shared `c_include/` is
  newer. Options: `cflags`,
  `ldflags` (after the sources), `nif: true` (a shared object with the
  ERTS headers, and priv/ linked into the build).
  """
  def compile(name, app_dir, sources, target, opts \\ []) do
    sources = Enum.map(sources, &Path.join(app_dir, &1))
    target = Path.join(app_dir, target)
    headers = Path.wildcard(Path.join(app_dir, "c_src/*.h")) ++ Path.wildcard("#{@shared}/*.h")

    result =
      if Mix.Utils.stale?(sources ++ headers, [target]),
        do: run_cc(name, app_dir, sources, target, opts),
        else: {:noop, []}

    if elem(result, 0) != :error, do: link_priv()
    result
  end

  defp run_cc(name, app_dir, sources, target, opts) do
    File.mkdir_p!(Path.dirname(target))
    cc = System.get_env("CC", "cc")
    nif = if opts[:nif], do: ["-fPIC", "-shared", "-I#{erts_include()}"], else: []

    args =
      ~w(-O2 -Wall -Wextra -Werror) ++
        ["-I#{@shared}"] ++
        nif ++
        Keyword.get(opts, :cflags, []) ++
        ["-o", target] ++ sources ++ Keyword.get(opts, :ldflags, [])

    case System.cmd(cc, args, stderr_to_stdout: true) do
      {_, 0} ->
        Mix.shell().info("Compiled #{Path.relative_to(target, app_dir)}")
        {:ok, []}

      {output, status} ->
        Mix.shell().error(output)

        diagnostic = %Mix.Task.Compiler.Diagnostic{
          compiler_name: name,
          file: hd(sources),
          message: "#{cc} exited with #{status}",
          position: nil,
          severity: :error
        }

        {:error, [diagnostic]}
    end
  end

  defp erts_include do
    dir = Path.join([:code.root_dir(), "erts-#{:erlang.system_info(:version)}", "include"])
    if File.exists?(Path.join(dir, "erl_nif.h")), do: dir, else: "/usr/lib/erlang/usr/include"
  end

  # Mix links priv/ into the build directory before the compilers run; on a
  # fresh checkout priv/ only exists once the compiler has run, so link it.
  defp link_priv do
    unless File.exists?(Path.join(Mix.Project.app_path(), "priv")) do
      Mix.Project.build_structure()
    end
  end
end
