defmodule ThinkingCap.VMFlagsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.VMFlags

  @root Path.expand("../../../..", __DIR__)

  test "the release, bin/run and bin/test start nodes with the same flags" do
    args =
      Path.join(@root, "rel/vm.args.eex")
      |> File.read!()
      |> String.split("\n")
      |> Enum.reject(&(&1 == "" or String.starts_with?(&1, "#")))
      |> Enum.flat_map(&String.split/1)

    for [flag, value] <- Enum.chunk_every(VMFlags.words(), 2) do
      assert Enum.chunk_every(args, 2, 1) |> Enum.member?([flag, value]),
             "rel/vm.args.eex lacks #{flag} #{value}"
    end

    for script <- ["bin/run", "bin/test"] do
      assert File.read!(Path.join(@root, script)) =~ VMFlags.string(),
             "#{script} does not export #{VMFlags.string()}"
    end
  end

  test "set?/0 tells an emulator started with every flag from one without" do
    ebin = Path.dirname(:code.which(VMFlags))
    probe = ["-pa", ebin, "-e", "IO.write(ThinkingCap.VMFlags.set?())"]

    assert {"true", 0} =
             System.cmd("elixir", probe, env: [{"ELIXIR_ERL_OPTIONS", VMFlags.string()}])

    # the scheduler flags alone are not enough
    assert {"false", 0} =
             System.cmd("elixir", probe,
               env: [{"ELIXIR_ERL_OPTIONS", "+sbwt none +sbwtdcpu none +sbwtdio none"}]
             )
  end
end
