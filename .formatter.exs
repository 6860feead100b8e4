[
  inputs: ["mix.exs", "config/*.exs", "bench/**/*.{ex,exs}", "test/**/*.{ex,exs}"],
  subdirectories: ["apps/*"]
]
