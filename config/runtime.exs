import Config

# A release deploys the ADF named by TC_ADF (rel/env.sh.eex): this node
# runs its share of the ADF's modules (ThinkingCap.Runtime.Deployment).
if config_env() == :prod do
  if adf = System.get_env("TC_ADF") do
    config :tc_runtime, deploy: Path.expand(adf)
  end
end
