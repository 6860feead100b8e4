import Config

config :logger, :console, format: "$time [$level] $metadata$message\n", metadata: [:node]

import_config "#{config_env()}.exs"
