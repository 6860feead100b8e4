defmodule ThinkingCap.Dashboard.Test.Browser do
  @moduledoc """
  A real browser for tests and benchmarks: Debian's chromium driven by npm
  `playwright-core` from a Node script (`test/support/js/driver.mjs`)
  spoken to through a port, one JSON command a line each way.

      {:ok, b} = Browser.start_link()
      {:ok, _} = Browser.open(b, url)
      {:ok, true} = Browser.wait(b, "window.tc && window.tc.connected")
      :ok = Browser.keydown(b, "ArrowUp")
      Browser.screenshot(b, "driving")

  The page is read and driven in JavaScript; what the robot does is checked
  by the caller on the blackboard. Pages are named (`page: "main"` unless
  given), each in its own browser context, so one browser can hold many
  independent dashboards. Closing the port (the owner exiting) closes the
  browser.
  """
  use GenServer

  @app_dir Path.expand("../..", __DIR__)
  @assets Path.join(@app_dir, "assets")
  @driver Path.join(@app_dir, "test/support/js/driver.mjs")
  @bundle Path.join(@app_dir, "priv/static/assets/app.js")
  @artifacts Path.join(@app_dir, "test/artifacts")
  @chromium "/usr/bin/chromium"

  @type browser :: GenServer.server()
  @type result :: {:ok, term()} | {:error, String.t()}

  # ---- set-up ------------------------------------------------------------------

  @doc "Where screenshots go (`apps/tc_dashboard/test/artifacts`)."
  @spec artifacts_dir() :: Path.t()
  def artifacts_dir, do: @artifacts

  @doc """
  Why no browser can run here (`{:error, reason}`), or `:ok`: Node, chromium
  and the npm packages must be installed (`bin/setup` does it).
  """
  @spec available() :: :ok | {:error, String.t()}
  def available do
    cond do
      System.find_executable("node") == nil ->
        {:error, "node is not installed"}

      not File.exists?(chromium()) ->
        {:error, "#{chromium()} is not installed"}

      not File.dir?(Path.join(@assets, "node_modules/playwright-core")) ->
        {:error, "run npm ci in #{@assets}"}

      true ->
        :ok
    end
  end

  @doc """
  Bundles the page's assets (esbuild, `npm run build`) when the bundle is
  missing or older than a source file, so tests run the page as written.
  """
  @spec ensure_assets!() :: :ok
  def ensure_assets! do
    sources = Path.wildcard(Path.join(@assets, "{js,css}/**/*.{js,css}"))

    stale? =
      not File.exists?(@bundle) or
        Enum.any?(sources, fn s -> mtime(s) > mtime(@bundle) end)

    if stale? do
      {out, status} =
        System.cmd("npm", ["run", "--silent", "build"], cd: @assets, stderr_to_stdout: true)

      if status != 0, do: raise("the dashboard's assets did not build:\n#{out}")
    end

    :ok
  end

  defp mtime(path), do: File.stat!(path, time: :posix).mtime

  defp chromium, do: System.get_env("CHROMIUM", @chromium)

  # ---- the browser ------------------------------------------------------------------

  @doc "Launches chromium (headless) and waits until it is ready."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []), do: GenServer.start_link(__MODULE__, opts)

  @doc "Closes the browser."
  @spec stop(browser()) :: :ok
  def stop(browser) do
    _ = command(browser, %{cmd: "quit"}, 5_000)
    GenServer.stop(browser, :normal, 5_000)
  catch
    :exit, _ -> :ok
  end

  @doc "Runs one driver command (see driver.mjs) and returns its result."
  @spec command(browser(), map(), timeout()) :: result()
  def command(browser, command, timeout \\ 15_000),
    do: GenServer.call(browser, {:command, command, timeout}, timeout + 1_000)

  @doc "Opens `url` in a new page (its own context) named `page`."
  @spec open(browser(), String.t(), keyword()) :: result()
  def open(browser, url, opts \\ []),
    do: command(browser, Map.merge(%{cmd: "open", url: url}, Map.new(opts)), 20_000)

  @doc "The JSON value of a JavaScript expression evaluated in the page."
  @spec eval(browser(), String.t(), keyword()) :: result()
  def eval(browser, expr, opts \\ []),
    do: command(browser, Map.merge(%{cmd: "eval", expr: expr}, Map.new(opts)))

  @doc "Waits until a JavaScript expression is truthy in the page; its value."
  @spec wait(browser(), String.t(), keyword()) :: result()
  def wait(browser, expr, opts \\ []) do
    timeout = Keyword.get(opts, :timeout, 5_000)
    command(browser, Map.merge(%{cmd: "wait", expr: expr}, Map.new(opts)), timeout + 2_000)
  end

  @doc "Holds a key down (Playwright's key names: `ArrowUp`, `KeyW`, `Space`...)."
  @spec keydown(browser(), String.t(), keyword()) :: :ok | {:error, String.t()}
  def keydown(browser, key, opts \\ []),
    do: ok(command(browser, Map.merge(%{cmd: "keydown", key: key}, Map.new(opts))))

  @doc "Lets go of a key."
  @spec keyup(browser(), String.t(), keyword()) :: :ok | {:error, String.t()}
  def keyup(browser, key, opts \\ []),
    do: ok(command(browser, Map.merge(%{cmd: "keyup", key: key}, Map.new(opts))))

  @doc "Clicks the element a CSS selector finds."
  @spec click(browser(), String.t(), keyword()) :: :ok | {:error, String.t()}
  def click(browser, selector, opts \\ []),
    do: ok(command(browser, Map.merge(%{cmd: "click", selector: selector}, Map.new(opts))))

  @doc "Saves a PNG of the page as `test/artifacts/NAME.png`; returns its path."
  @spec screenshot(browser(), String.t(), keyword()) :: result()
  def screenshot(browser, name, opts \\ []) do
    File.mkdir_p!(@artifacts)
    path = Path.join(@artifacts, "#{name}.png")
    command(browser, Map.merge(%{cmd: "screenshot", path: path}, Map.new(opts)))
  end

  @doc "The page's console messages and errors so far."
  @spec console(browser(), keyword()) :: result()
  def console(browser, opts \\ []),
    do: command(browser, Map.merge(%{cmd: "console"}, Map.new(opts)))

  ## For tests: the same, failing the test on an error

  @doc "Opens `url` (`open/3`); fails the test unless the page loaded (200)."
  @spec open!(browser(), String.t()) :: map()
  def open!(browser, url) do
    case open(browser, url) do
      {:ok, %{"status" => 200} = page} -> page
      other -> ExUnit.Assertions.flunk("opening #{url}: #{inspect(other)}")
    end
  end

  @doc "The value of `expr` in the page (`eval/3`); fails the test on an error."
  @spec eval!(browser(), String.t()) :: term()
  def eval!(browser, expr) do
    case eval(browser, expr) do
      {:ok, value} -> value
      {:error, message} -> ExUnit.Assertions.flunk("#{expr}: #{message}")
    end
  end

  @doc """
  Waits until `expr` is truthy (`wait/3`, `timeout:` default 5 s) and
  answers its value; fails the test with the page's console otherwise.
  """
  @spec wait!(browser(), String.t(), keyword()) :: term()
  def wait!(browser, expr, opts \\ []) do
    case wait(browser, expr, opts) do
      {:ok, value} ->
        value

      {:error, message} ->
        {:ok, log} = console(browser)

        ExUnit.Assertions.flunk(
          "waiting for #{expr}: #{message}\nthe page's console: #{inspect(log)}"
        )
    end
  end

  @doc "The page's errors so far (console lines of errors and uncaught exceptions)."
  @spec page_errors(browser()) :: [String.t()]
  def page_errors(browser) do
    {:ok, log} = console(browser)
    Enum.filter(log, &String.starts_with?(&1, ["pageerror", "error"]))
  end

  defp ok({:ok, _}), do: :ok
  defp ok(error), do: error

  # ---- the port ---------------------------------------------------------------------

  @impl true
  def init(opts) do
    case available() do
      :ok ->
        node = System.find_executable("node")
        timeout = Keyword.get(opts, :launch_timeout, 30_000)

        port =
          Port.open({:spawn_executable, node}, [
            :binary,
            :exit_status,
            {:line, 65_536},
            {:args, [@driver]},
            {:cd, @app_dir},
            {:env, [{~c"CHROMIUM", String.to_charlist(chromium())}]}
          ])

        await_ready(%{port: port, buffer: "", next: 1, calls: %{}}, timeout)

      {:error, reason} ->
        {:stop, reason}
    end
  end

  defp await_ready(state, timeout) do
    receive do
      {port, {:data, data}} when port == state.port ->
        case collect(state, data) do
          {[%{"ok" => true, "result" => "ready"} | _], state} -> {:ok, state}
          {[%{"ok" => false, "error" => error} | _], _state} -> {:stop, error}
          {_, state} -> await_ready(state, timeout)
        end

      {port, {:exit_status, status}} when port == state.port ->
        {:stop, "the browser driver exited (#{status}) before it was ready"}
    after
      timeout -> {:stop, "the browser did not start within #{timeout} ms"}
    end
  end

  @impl true
  def handle_call({:command, command, timeout}, from, state) do
    id = state.next
    Port.command(state.port, [:jiffy.encode(Map.put(command, :id, id)), ?\n])
    timer = Process.send_after(self(), {:timeout, id}, timeout)
    {:noreply, %{state | next: id + 1, calls: Map.put(state.calls, id, {from, timer})}}
  end

  @impl true
  def handle_info({port, {:data, data}}, %{port: port} = state) do
    {messages, state} = collect(state, data)
    {:noreply, Enum.reduce(messages, state, &answer/2)}
  end

  def handle_info({port, {:exit_status, status}}, %{port: port} = state) do
    for {_id, {from, _timer}} <- state.calls,
        do: GenServer.reply(from, {:error, "the browser driver exited (#{status})"})

    {:stop, :normal, %{state | calls: %{}}}
  end

  def handle_info({:timeout, id}, state) do
    case Map.pop(state.calls, id) do
      {{from, _}, calls} ->
        GenServer.reply(from, {:error, "no answer from the browser"})
        {:noreply, %{state | calls: calls}}

      {nil, _} ->
        {:noreply, state}
    end
  end

  def handle_info(_message, state), do: {:noreply, state}

  defp answer(%{"id" => id} = message, state) do
    case Map.pop(state.calls, id) do
      {{from, timer}, calls} ->
        Process.cancel_timer(timer)

        reply =
          if message["ok"],
            do: {:ok, message["result"]},
            else: {:error, message["error"]}

        GenServer.reply(from, reply)
        %{state | calls: calls}

      {nil, _} ->
        state
    end
  end

  defp answer(_message, state), do: state

  # whole lines of JSON out of the port's {:eol, _} / {:noeol, _} pieces
  defp collect(state, {:noeol, part}), do: {[], %{state | buffer: state.buffer <> part}}

  defp collect(state, {:eol, part}) do
    line = state.buffer <> part
    state = %{state | buffer: ""}

    case decode(line) do
      {:ok, message} -> {[message], state}
      :error -> {[], state}
    end
  end

  defp decode(line) do
    {:ok, :jiffy.decode(line, [:return_maps, :use_nil])}
  catch
    _, _ -> :error
  end
end
