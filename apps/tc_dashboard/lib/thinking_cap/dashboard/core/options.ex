defmodule ThinkingCap.Dashboard.Core.Options do
  @moduledoc false
  # The dashboard's options, validated up front (unknown keys and wrong
  # types raise ArgumentError): the ones an ADF's `dashboard:` section
  # shares, defined once in Config.DashboardOptions, and those only a
  # running dashboard takes.

  alias ThinkingCap.Config.{DashboardOptions, Schema}

  @string_or_nil {:or, [:string, {:one_of, [nil]}]}

  @running_fields [
    token:
      {@string_or_nil,
       default: nil, doc: "the access token, 8 bytes at least (default: a new random one)"},
    world:
      {:any, default: nil, doc: "the WDF shown on the map (a path or a `ThinkingCap.Config.WDF`)"},
    static_dir:
      {@string_or_nil, default: nil, doc: "the page's files (default: the app's `priv/static`)"}
  ]
  @fields DashboardOptions.fields() ++ @running_fields

  @doc "The options as a Markdown table."
  @spec docs() :: String.t()
  def docs, do: Schema.describe(@fields)

  @doc "Validates `opts` and fills in the defaults; raises ArgumentError."
  @spec validate!(keyword() | map()) :: map()
  def validate!(opts) do
    st = %{file: "dashboard options", positions: %{}, errors: []}
    {config, st} = Schema.check_at(st, {:keyword, @fields}, Enum.to_list(opts), [:dashboard])

    case Schema.errors(st) do
      [] -> :ok
      errors -> raise ArgumentError, Enum.map_join(errors, "; ", & &1.message)
    end

    if is_binary(config.token) and byte_size(config.token) < 8,
      do: raise(ArgumentError, "dashboard.token: the token must be at least 8 bytes")

    %{config | static_dir: config.static_dir || Application.app_dir(:tc_dashboard, "priv/static")}
  end
end
