defmodule ThinkingCap.Dashboard.Core.OptionsTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Config
  alias ThinkingCap.Config.DashboardOptions
  alias ThinkingCap.Dashboard.Core.Options

  @examples Path.expand("../../../../../../priv/examples", __DIR__)

  test "an ADF's dashboard section and the dashboard's options have the same defaults" do
    adf = Config.read!(Path.join(@examples, "office.adf"))
    defaults = Options.validate!([])

    for key <- DashboardOptions.keys(), key not in [:host, :port] do
      assert Map.fetch!(adf.dashboard, key) == Map.fetch!(defaults, key), "#{key}"
    end

    assert %{token: nil, world: nil, rosbridge_port: 9090, max_frame: 1_048_576} = defaults
    assert defaults.static_dir == Application.app_dir(:tc_dashboard, "priv/static")
  end

  test "what an ADF's section may say, the dashboard takes" do
    adf =
      Config.ADF.from_data(
        [
          robot: :r1,
          modules: [],
          dashboard: [enabled: true, rosbridge_port: nil, origins: ["http://x"], telemetry_hz: 5]
        ],
        "t.adf",
        %{}
      )

    assert {:ok, %{dashboard: dashboard}} = adf
    config = Options.validate!(Map.take(dashboard, DashboardOptions.keys()))
    assert %{rosbridge_port: nil, origins: ["http://x"], telemetry_hz: 5} = config
  end

  test "wrong values and unknown keys raise ArgumentError naming the key" do
    assert_raise ArgumentError, ~r/dashboard\.port: expected an integer from 0 to 65535/, fn ->
      Options.validate!(port: -1)
    end

    assert_raise ArgumentError, ~r/unknown key :prot in dashboard; did you mean :port\?/, fn ->
      Options.validate!(prot: 4000)
    end

    assert_raise ArgumentError, ~r/dashboard\.origins\[1\]: expected a string/, fn ->
      Options.validate!(origins: ["http://a", 1])
    end

    assert_raise ArgumentError, ~r/dashboard\.token: the token must be at least 8 bytes/, fn ->
      Options.validate!(token: "short")
    end
  end

  test "a map is taken as a keyword list is" do
    assert %{port: 0, public_view: true} = Options.validate!(%{port: 0, public_view: true})
  end
end
