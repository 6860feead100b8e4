defmodule ThinkingCap.Examples.ModuleGuideTest do
  # docs/module_guide.md quotes the repository's code; every quote must
  # still be there, word for word, so the guide cannot drift from it.
  use ExUnit.Case, async: true

  alias ThinkingCap.Config.Schema

  @root Path.expand("../../../../..", __DIR__)
  @guide Path.join(@root, "docs/module_guide.md")

  defp guide, do: File.read!(@guide)

  test "every quote of the guide is in the file it names" do
    quotes = Regex.scan(~r/<!-- quote: (\S+) -->\n```elixir\n(.*?)\n```/s, guide())
    assert length(quotes) >= 10

    for [_, path, code] <- quotes do
      source = File.read!(Path.join(@root, path))
      assert String.contains?(source, code), "docs/module_guide.md quotes #{path}:\n#{code}"
    end
  end

  test "the params the guide shows are those mix tc.check --explain prints" do
    [_, name, shown] = Regex.run(~r/<!-- explain: (\S+) -->\n```text\n(.*?)\n```/s, guide())

    module = Module.concat([name])
    assert String.contains?(shown, Schema.describe(module.params()))
  end

  test "the guide's module is the one the README points to" do
    assert File.read!(Path.join(@root, "README.md")) =~ "docs/module_guide.md"
    assert guide() =~ "ThinkingCap.Examples.WallFollower"
  end
end
