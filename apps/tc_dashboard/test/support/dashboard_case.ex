defmodule ThinkingCap.Dashboard.Test.Case do
  @moduledoc """
  A case template for tests that run the dashboard: starts it on free ports
  with a known token before each test (options from the `:dashboard` tag)
  and stops it after; tests run one at a time (the dashboard is one per node).
  """
  use ExUnit.CaseTemplate

  alias ThinkingCap.Dashboard.Test.WSClient

  @token "test-token-0123456789"

  using do
    quote do
      import ThinkingCap.Dashboard.Test.Case
      alias ThinkingCap.Dashboard.Test.WSClient
    end
  end

  setup context do
    opts =
      [port: 0, rosbridge_port: nil, token: @token]
      |> Keyword.merge(context[:dashboard] || [])

    {:ok, info} = ThinkingCap.Dashboard.start(opts)
    on_exit(fn -> ThinkingCap.Dashboard.stop() end)
    %{dashboard: info}
  end

  @doc "The token the dashboard runs with in these tests."
  def token, do: @token

  @doc "Opens the page's socket (with the token unless `query` says otherwise)."
  def connect(info, query \\ "?token=#{@token}", headers \\ []) do
    WSClient.connect("127.0.0.1", info.port, "/ws" <> query, headers)
  end

  @doc "Opens the page's socket and reads its welcome."
  def connect!(info, query \\ "?token=#{@token}") do
    {:ok, client} = connect(info, query)
    {:ok, welcome, client} = WSClient.recv_json_until(client, &(&1["op"] == "welcome"))
    {welcome, client}
  end

  @doc "Sends `message` (a map, given an id) and returns the reply with that id."
  def request(client, message) do
    id = System.unique_integer([:positive])
    :ok = WSClient.send_text(client, :jiffy.encode(Map.put(message, :id, id)))

    {:ok, reply, client} =
      WSClient.recv_json_until(client, &(&1["id"] == id and &1["op"] != "tuple"))

    {reply, client}
  end
end
