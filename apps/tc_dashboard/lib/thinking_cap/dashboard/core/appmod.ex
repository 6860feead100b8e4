defmodule ThinkingCap.Dashboard.Core.Appmod do
  @moduledoc false
  # The yaws appmod in front of every WebSocket: the page's `/ws` and every
  # path of the rosbridge port. It checks the Origin header (browsers send
  # one: it must be the dashboard's own origin or one the options list;
  # clients without one, such as Node or Foxglove desktop, pass), reads the
  # access token from the query string, refuses viewers without it unless
  # `public_view` is on (for the handlers that say so), and upgrades to a
  # WebSocket served by Core.Socket with the handler named in the server's
  # opaque data.

  import ThinkingCap.Dashboard.Core.Records
  alias ThinkingCap.Dashboard.Core.{Access, Socket}

  @doc false
  def out(arg) do
    opaque = Map.new(arg(arg, :opaque))
    config = ThinkingCap.Dashboard.config()
    headers = arg(arg, :headers)
    origin = header(headers, "origin")
    query = Access.query(arg)
    control = Access.valid_token?(query["token"], config.token)

    cond do
      config == nil ->
        refuse(503, "the dashboard is not running")

      origin != nil and not Access.origin_allowed?(origin, config) ->
        refuse(403, "origin #{origin} is not allowed")

      opaque[:view_needs_token] and not control and not config.public_view ->
        refuse(401, "an access token is required (the URL printed at start has it)")

      true ->
        conn = %{
          control: control,
          query: query,
          peer: arg(arg, :client_ip_port),
          origin: origin,
          config: config
        }

        {:websocket, Socket,
         [
           callback: {:basic, {opaque[:handler], conn}},
           max_frame_size: config.max_frame,
           max_message_size: config.max_frame,
           keepalive: true,
           keepalive_timeout: 20_000,
           keepalive_grace_period: 5_000,
           drop_on_timeout: true
         ]}
    end
  end

  defp refuse(status, message),
    do: [{:status, status}, {:content, 'text/plain', String.to_charlist(message <> "\n")}]

  defp header(headers, name) do
    case :yaws_api.get_header(headers, name) do
      :undefined -> nil
      value -> to_string(value)
    end
  end
end
