defmodule Mix.Tasks.Tc.Demo do
  @shortdoc "Runs the two-node blackboard demo"
  @moduledoc """
  Runs the two-node blackboard demo (`ThinkingCap.Blackboard.Demo`): a
  sensor module on a second node streams poses, this node subscribes,
  takes jobs written across nodes and prints what it sees.

      elixir --name thinkingcap@127.0.0.1 -S mix tc.demo [--seconds N]
  """
  use Mix.Task

  @impl true
  def run(args) do
    {opts, _rest} = OptionParser.parse!(args, strict: [seconds: :integer])
    Mix.Task.run("app.start")

    unless Node.alive?() do
      Mix.raise(
        "mix tc.demo needs a distributed node: elixir --name thinkingcap@127.0.0.1 -S mix tc.demo"
      )
    end

    ThinkingCap.Blackboard.Demo.run(seconds: opts[:seconds])
  end
end
