defmodule ThinkingCap.Umbrella.MixProject do
  use Mix.Project

  def project do
    [
      apps_path: "apps",
      version: "0.1.0",
      start_permanent: Mix.env() == :prod,
      elixirc_options: [warnings_as_errors: true],
      deps: [],
      releases: releases()
    ]
  end

  # One release, installed on every CPU of the robot; which node it is,
  # its cookie, its ADF and its network interface come from the
  # environment when it starts (rel/env.sh.eex, rel/README.md).
  defp releases do
    [
      thinking_cap: [
        applications: [
          tc_blackboard: :permanent,
          tc_runtime: :permanent,
          tc_robot: :permanent,
          tc_sim: :permanent,
          tc_cognition: :permanent,
          tc_blackbox: :permanent,
          tc_dashboard: :permanent,
          # loaded, never started as an application: the dashboard runs
          # its processes under its own supervisor when an ADF wants it
          # (apps/tc_dashboard/mix.exs puts it on the code path)
          yaws: :load
        ],
        include_executables_for: [:unix],
        rel_templates_path: "rel",
        steps: [:assemble]
      ]
    ]
  end
end
