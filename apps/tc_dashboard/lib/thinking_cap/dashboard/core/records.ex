defmodule ThinkingCap.Dashboard.Core.Records do
  @moduledoc false
  # yaws's records, read from Debian's yaws_api.hrl at compile time.
  require Record

  @hrl "/usr/lib/yaws-*/include/yaws_api.hrl" |> Path.wildcard() |> Enum.sort() |> List.last()
  @external_resource @hrl

  Record.defrecord(:arg, Record.extract(:arg, from: @hrl))
  Record.defrecord(:http_request, Record.extract(:http_request, from: @hrl))
  Record.defrecord(:headers, Record.extract(:headers, from: @hrl))
  Record.defrecord(:ws_state, Record.extract(:ws_state, from: @hrl))
end
