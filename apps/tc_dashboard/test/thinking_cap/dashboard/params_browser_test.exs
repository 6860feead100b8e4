defmodule ThinkingCap.Dashboard.ParamsBrowserTest do
  # The Params panel in a real browser (chromium, as browser_test.exs):
  # a simulated robot with its control cycle (the Blender), the page's
  # panel generated from the Blender's schema, a param set from it reaching
  # the module, and refusals shown with their reasons.
  use ExUnit.Case, async: false

  alias ThinkingCap.{Blackboard, Dashboard, Runtime, Sim}
  alias ThinkingCap.Dashboard.Test.Browser
  import Browser, only: [eval!: 2, wait!: 2]

  @moduletag :browser
  @moduletag :tmp_dir

  @examples Path.expand("../../../../../priv/examples", __DIR__)
  @wdf Path.join(@examples, "office.wdf")

  setup_all do
    :ok = Browser.ensure_assets!()
    {:ok, browser} = Browser.start_link()
    on_exit(fn -> Browser.stop(browser) end)
    %{browser: browser}
  end

  setup %{tmp_dir: dir} do
    robot = :"pweb#{System.unique_integer([:positive])}"
    control = :"control_#{robot}"
    path = Path.join(dir, "params.adf")

    File.write!(path, """
    [
      robot: :#{robot},
      rdf: "#{@examples}/office_robot.rdf",
      wdf: "#{@wdf}",
      dashboard: [enabled: true, port: 0, rosbridge_port: 0],
      modules: [
        base_#{robot}: [module: ThinkingCap.Sim.Robot, activity: :periodic, period: 0.01,
                         deadline: 0.005, fallback: :stop, params: [at: {16.0, 1.8, 0.0}, seed: 5]],
        #{control}: [module: ThinkingCap.Control.Blender, activity: :periodic, period: 0.1,
                     deadline: 0.05]
      ]
    ]
    """)

    {:ok, _} = Runtime.start(path)

    on_exit(fn ->
      Runtime.stop(control)
      Runtime.stop(:"base_#{robot}")
      Dashboard.stop()
      with {:ok, sim} <- Sim.Worlds.lookup(@wdf), do: Sim.remove_robot(sim, robot)
    end)

    {:ok, info} = Dashboard.await(10_000)
    {:ok, _} = Blackboard.rd({:robot, robot, :_}, 5_000)
    %{robot: robot, name: Atom.to_string(robot), control: control, info: info}
  end

  test "a param set from the panel reaches the module; a refusal shows its reason", ctx do
    b = ctx.browser
    assert {:ok, %{"status" => 200}} = Browser.open(b, ctx.info.url <> "&robot=#{ctx.name}")
    wait!(b, "tc.connected && tc.canControl && tc.selected === #{js(ctx.name)}")
    :ok = Browser.click(b, ~s(.tabs button[data-tab="params"]))

    row = ~s(#tab-params [data-module="#{ctx.control}"] [data-key="max_speed"])
    input = row <> " .param-input"

    # generated from the Blender's schema: its limit from the RDF, the range shown
    assert wait!(b, "(document.querySelector(#{js(input)}) || {}).value") == "0.4"
    assert eval!(b, "document.querySelector(#{js(input)}).type") == "number"
    assert eval!(b, "document.querySelector(#{js(input)}).max") == "10"

    assert eval!(b, "document.querySelector(#{js(row <> " .param-hint")}).textContent") =~
             "0 … 10"

    # read-only params are shown disabled
    radius = ~s(#tab-params [data-module="#{ctx.control}"] [data-key="radius"] .param-input)
    assert eval!(b, "document.querySelector(#{js(radius)}).disabled") == true
    assert eval!(b, "document.querySelector(#{js(input)}).disabled") == false

    # set from the panel: the module drives within it from its next cycle
    type!(b, input, "0.25")
    :ok = Browser.click(b, row <> " button.set")
    wait!(b, "document.querySelector(#{js(input)}).value === '0.25'")
    await(fn -> Runtime.get_params(ctx.control) |> elem(1) |> Map.get(:max_speed) == 0.25 end)
    pid = Runtime.whereis(ctx.control)
    assert :sys.get_state(pid).mstate.limits.max_speed == 0.25

    recorded =
      for {:param, _, %{module: m} = p} <- Blackboard.rd_all({:param, ctx.robot, :_}),
          m == ctx.control,
          into: %{},
          do: {p.key, p}

    assert %{value: 0.25, by: "page " <> _} = recorded.max_speed

    # out of range: refused, the range shown beside the field; the module keeps its value
    type!(b, input, "20")
    :ok = Browser.click(b, row <> " button.set")
    error = row <> " .param-error"

    assert wait!(b, "document.querySelector(#{js(error)}).textContent") ==
             "max_speed: expected a number from 0.0 to 10.0, got 20"

    # above the robot's own limit: the module refuses it, naming the limit
    type!(b, input, "0.9")
    :ok = Browser.click(b, row <> " button.set")

    assert wait!(
             b,
             "(t => t.includes('above') && t)(document.querySelector(#{js(error)}).textContent)"
           ) =~ "0.9 is above the robot's max_speed of 0.4 (its RDF)"

    assert {:ok, %{max_speed: 0.25}} = Runtime.get_params(ctx.control)
    assert :sys.get_state(pid).mstate.limits.max_speed == 0.25

    Browser.screenshot(b, "params_panel")
    {:ok, log} = Browser.console(b)
    assert Enum.filter(log, &String.starts_with?(&1, "pageerror")) == []
  end

  # what a user typing into the field leaves there
  defp type!(b, selector, text) do
    eval!(b, """
    (() => {
      const input = document.querySelector(#{js(selector)});
      input.focus();
      input.value = #{js(text)};
      input.dispatchEvent(new Event('input', { bubbles: true }));
      return true;
    })()
    """)
  end

  defp js(string), do: :jiffy.encode(string)

  defp await(fun, timeout \\ 2_000) do
    deadline = System.monotonic_time(:millisecond) + timeout

    Stream.repeatedly(fn ->
      cond do
        fun.() -> true
        System.monotonic_time(:millisecond) > deadline -> flunk("not reached in #{timeout} ms")
        true -> Process.sleep(10) && nil
      end
    end)
    |> Enum.find(& &1)
  end
end
