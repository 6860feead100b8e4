defmodule Mix.Tasks.Tc.Run do
  @shortdoc "Runs the main job (bin/run): for now the two-node blackboard demo"
  @moduledoc """
  Runs ThinkingCap's main job. Until the simulator lands this is the
  two-node blackboard demo (`ThinkingCap.Blackboard.Demo`).

      elixir --name thinkingcap@127.0.0.1 -S mix tc.run [--seconds N]

  `bin/run` does the set-up and starts it so.
  """
  use Mix.Task

  @impl true
  def run(args) do
    {opts, _rest} = OptionParser.parse!(args, strict: [seconds: :integer])
    Mix.Task.run("app.start")

    unless Node.alive?() do
      Mix.raise(
        "mix tc.run needs a distributed node: elixir --name thinkingcap@127.0.0.1 -S mix tc.run"
      )
    end

    ThinkingCap.Blackboard.Demo.run(seconds: opts[:seconds])
  end
end
