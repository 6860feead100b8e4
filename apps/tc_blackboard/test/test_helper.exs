# Multi-node tests start peer nodes with distributed Erlang: they need epmd.
{_, 0} = System.cmd("epmd", ["-daemon"])
ExUnit.start(capture_log: true)
