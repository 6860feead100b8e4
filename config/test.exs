import Config

config :logger, level: :warning

# the black box is on by default wherever tc_blackbox runs; the tests that
# want one ask for it in their ADF (black_box: [enabled: true, dir: ...])
config :tc_blackbox, black_box_by_default: false
