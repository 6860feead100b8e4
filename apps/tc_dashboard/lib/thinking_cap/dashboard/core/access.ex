defmodule ThinkingCap.Dashboard.Core.Access do
  @moduledoc false
  # The access token and the origin rule.

  @doc "A new random access token (URL-safe, 128 bits)."
  @spec new_token() :: String.t()
  def new_token, do: 16 |> :crypto.strong_rand_bytes() |> Base.url_encode64(padding: false)

  @doc "Whether `given` is the token, compared in constant time."
  @spec valid_token?(term(), String.t() | nil) :: boolean()
  def valid_token?(given, token)
      when is_binary(given) and is_binary(token) and byte_size(given) == byte_size(token),
      do: :crypto.hash_equals(given, token)

  def valid_token?(_given, _token), do: false

  @doc """
  Whether a browser `origin` may open a socket: the dashboard's own origin
  (under its host name, and under `localhost`/`127.0.0.1` when it listens on
  loopback) or one of `config.origins`.
  """
  @spec origin_allowed?(String.t(), map()) :: boolean()
  def origin_allowed?(origin, config) do
    origin = String.trim_trailing(origin, "/")
    origin in own_origins(config) or origin in config.origins
  end

  defp own_origins(config) do
    hosts =
      if config.host in ["127.0.0.1", "::1", "0.0.0.0"],
        do: [config.host, "localhost", "127.0.0.1"],
        else: [config.host]

    for host <- Enum.uniq(hosts), do: "http://#{host}:#{config.port}"
  end

  @doc "A request's query string as a map of strings (empty when it cannot be read)."
  @spec query(tuple()) :: %{String.t() => String.t()}
  def query(arg) do
    arg
    |> :yaws_api.parse_query()
    |> Map.new(fn {k, v} -> {to_string(k), if(v == :undefined, do: "", else: to_string(v))} end)
  rescue
    _ -> %{}
  end
end
