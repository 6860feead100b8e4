defmodule ThinkingCap.Dashboard.ParamsTest do
  # live parameters over the page's protocol: the params op, set_param
  use ThinkingCap.Dashboard.Test.Case, async: false

  alias ThinkingCap.{Blackboard, Config, Runtime}

  @moduletag :tmp_dir

  defmodule Tunable do
    @moduledoc false
    use ThinkingCap.Module

    @impl true
    def params do
      [
        max_speed: {{:number_range, 0.0, 1.0}, default: 0.2, doc: "m/s"},
        mode: {{:one_of, [:slow, :fast]}, default: :slow, doc: "a choice"},
        enabled: {:boolean, default: true, doc: "a flag"},
        goal: {:point, default: {0.0, 0.0}, doc: "not for a form"},
        seed: {:integer, default: 1, read_only: true, doc: "read at start"}
      ]
    end

    @impl true
    def init(_params, ctx), do: {:ok, ctx.params}

    @impl true
    def handle_param(key, value, params), do: {[], Map.put(params, key, value)}
  end

  setup %{tmp_dir: dir} do
    robot = :"pr#{System.unique_integer([:positive])}"
    Blackboard.out({:robot, robot, %{limits: %{}}}, key: {:robot, robot})
    path = Path.join(dir, "p.adf")

    File.write!(path, """
    [robot: :#{robot}, modules: [tunable_#{robot}: [module: #{inspect(Tunable)}, activity: :event]]]
    """)

    {:ok, [%{pid: pid}]} = Runtime.start(Config.read!(path))
    on_exit(fn -> Runtime.stop(:"tunable_#{robot}") end)
    %{robot: robot, name: Atom.to_string(robot), module: "tunable_#{robot}", pid: pid}
  end

  test "params lists a robot's modules' params with their inputs", ctx do
    {_welcome, client} = connect!(ctx.dashboard)
    {reply, client} = request(client, %{op: "params", robot: ctx.name})
    assert %{"op" => "params", "modules" => [module]} = reply
    assert %{"name" => name, "live" => true, "fields" => fields} = module
    assert name == ctx.module
    by_key = Map.new(fields, &{&1["key"], &1})

    assert %{
             "input" => "number",
             "min" => 0.0,
             "max" => 1.0,
             "value" => 0.2,
             "read_only" => false
           } = by_key["max_speed"]

    assert %{"input" => "choice", "choices" => ["slow", "fast"], "value" => "slow"} =
             by_key["mode"]

    assert %{"input" => "boolean", "value" => true} = by_key["enabled"]
    assert %{"input" => "other", "value" => [0.0, 0.0]} = by_key["goal"]
    assert %{"input" => "integer", "read_only" => true} = by_key["seed"]
    WSClient.close(client)
  end

  test "set_param reaches the module and is recorded; refusals say why", ctx do
    {_welcome, client} = connect!(ctx.dashboard)

    set = fn client, key, value ->
      request(client, %{
        op: "set_param",
        robot: ctx.name,
        module: ctx.module,
        key: key,
        value: value
      })
    end

    {%{"op" => "ok"}, client} = set.(client, "max_speed", 0.35)
    {%{"op" => "ok"}, client} = set.(client, "mode", "fast")
    {%{"op" => "ok"}, client} = set.(client, "enabled", false)
    assert %{max_speed: 0.35, mode: :fast, enabled: false} = :sys.get_state(ctx.pid).mstate

    recorded =
      for {:param, _, p} <- Blackboard.rd_all({:param, ctx.robot, :_}), into: %{}, do: {p.key, p}

    assert %{value: 0.35, by: "page " <> _, module: module} = recorded.max_speed
    assert Atom.to_string(module) == ctx.module
    assert %{value: :fast} = recorded.mode

    for {key, value, why} <- [
          {"max_speed", 3, "max_speed: expected a number from 0.0 to 1.0, got 3"},
          {"max_speed", "fast", "max_speed: expected a number from 0.0 to 1.0, got \"fast\""},
          {"mode", "medium", "mode: expected one of slow, fast, got \"medium\""},
          {"enabled", 1, "enabled: expected true or false, got 1"},
          {"seed", 2, "read-only"},
          {"goal", "here", "cannot be set from the dashboard"},
          {"max_sped", 0.1, "has no param \"max_sped\""}
        ] do
      {reply, _} = set.(client, key, value)
      assert %{"op" => "error", "message" => message} = reply
      assert message =~ why, "#{key} = #{inspect(value)}: #{message}"
    end

    # malformed messages: a clear error, never a crash
    for bad <- [
          %{op: "set_param", robot: ctx.name, module: ctx.module, key: "max_speed"},
          %{op: "set_param", robot: ctx.name, module: ctx.module, key: "max_speed", value: [1]},
          %{
            op: "set_param",
            robot: ctx.name,
            module: ctx.module,
            key: "max_speed",
            value: %{a: 1}
          },
          %{op: "set_param", robot: ctx.name, module: 7, key: "max_speed", value: 0.1},
          %{op: "set_param", robot: ctx.name, module: "nope", key: "max_speed", value: 0.1},
          %{op: "set_param", robot: "nobody", module: ctx.module, key: "max_speed", value: 0.1},
          %{op: "params", robot: 5}
        ] do
      {reply, _} = request(client, bad)
      assert %{"op" => "error", "message" => message} = reply
      assert is_binary(message) and message != ""
    end

    assert %{max_speed: 0.35, mode: :fast, enabled: false, seed: 1} =
             :sys.get_state(ctx.pid).mstate

    {%{"op" => "pong"}, _} = request(client, %{op: "ping"})
    WSClient.close(client)
  end

  @tag dashboard: [public_view: true]
  test "setting a param needs the token; reading them does not", ctx do
    {_welcome, client} = connect!(ctx.dashboard, "")
    {%{"op" => "params"}, client} = request(client, %{op: "params", robot: ctx.name})

    {reply, _} =
      request(client, %{
        op: "set_param",
        robot: ctx.name,
        module: ctx.module,
        key: "max_speed",
        value: 0.5
      })

    assert %{"op" => "error", "message" => message} = reply
    assert message =~ "access token"
    assert :sys.get_state(ctx.pid).mstate.max_speed == 0.2
    WSClient.close(client)
  end
end
