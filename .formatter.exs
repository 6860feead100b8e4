[
  inputs: ["mix.exs", "config/*.exs", "mix/*.exs", "bench/**/*.{ex,exs}", "test/**/*.{ex,exs}"],
  subdirectories: ["apps/*"]
]
