defmodule ThinkingCap.Console do
  @moduledoc """
  Helpers for a remote shell on a running robot (a release's
  `bin/thinking_cap remote`, or `iex --remsh`):

      iex> import ThinkingCap.Console
      iex> estop(:r1)              # stop the robot now (latched)
      iex> modules()               # what runs where
      iex> cluster()               # this node's view of the deployment
      iex> timing()                # the control cycle's figures, every node
      iex> tuples({:pose, :_, :_}) # blackboard tuples by template
      iex> move(:control, :brain)  # move a module (after a failover)
      iex> params(:control)        # a module's params, their types and values
      iex> param(:control, :max_speed, 0.3)  # set one while it runs
      iex> gave_up()               # modules whose supervision layer gave up
      iex> resume(:r1)             # bring their layers back
      iex> release_estop(:r1)
      iex> dump(:r1)               # write the black box's last minute to a file

  Each prints a table and returns its data, so the result can be worked
  on in the shell.
  """

  alias ThinkingCap.{Blackboard, Runtime}
  alias ThinkingCap.Runtime.Deployment
  alias ThinkingCap.Tuples
  require Tuples

  @doc """
  Engages the E-stop of `robot`: its base stops at its next cycle and stays
  stopped (teleoperation and autonomy alike) until `release_estop/1`.
  """
  @spec estop(atom()) :: :ok
  def estop(robot) do
    {estop, opts} = Tuples.keyed(Tuples.estop_engaged(robot, :console))
    :ok = Blackboard.out(estop, opts)
    IO.puts("#{robot}: E-stop engaged")
  end

  @doc """
  Asks the black box of `robot` (`ThinkingCap.BlackBox`, wherever it
  runs) to dump its last seconds to an MCAP file. The dump goes on for
  the black box's `after:` seconds; it is announced on the blackboard as
  `{:black_box_dump, robot, %{path: ...}}` when written.
  """
  @spec dump(atom(), String.t() | atom()) :: :ok
  def dump(robot, reason \\ "console") do
    request = Tuples.black_box_request(robot, %{reason: reason, by: :console, at: now_ms()})
    {request, opts} = Tuples.keyed(request)
    :ok = Blackboard.out(request, opts)
    IO.puts("#{robot}: black-box dump requested (#{reason})")
  end

  defp now_ms, do: System.os_time(:millisecond)

  @doc "Releases the E-stop of `robot`: autonomy (or teleoperation) drives again."
  @spec release_estop(atom()) :: :ok
  def release_estop(robot) do
    {estop, opts} = Tuples.keyed(Tuples.estop_released(robot, :console))
    :ok = Blackboard.out(estop, opts)
    IO.puts("#{robot}: E-stop released")
  end

  @doc "Every running module of the cluster: where it runs and how it is released."
  @spec modules() :: [Runtime.module_info()]
  def modules do
    modules = Runtime.which_modules()

    table(
      ["module", "implementation", "node", "activity", "layer"],
      for(m <- modules, do: [m.name, inspect(m.module), m.node, m.activity, m[:layer]])
    )

    modules
  end

  @doc """
  The modules whose supervision layer gave up (`ThinkingCap.Runtime.Supervision`),
  every robot's: the module, its layer and node, why, and the modules
  stopped with it. Their robots' E-stops are latched.
  """
  @spec gave_up() :: [map()]
  def gave_up do
    gave_up =
      for Tuples.module_gave_up(robot, g) <- Blackboard.rd_all(Tuples.module_gave_up()),
          do: Map.put(g, :robot, robot)

    table(
      ["robot", "module", "layer", "node", "reason", "stopped with it"],
      for(
        g <- gave_up,
        do: [
          g.robot,
          g.module,
          g.layer,
          g.node,
          g.reason,
          Enum.join(g.stopped -- [g.module], ", ")
        ]
      )
    )

    gave_up
  end

  @doc """
  Brings back `robot`'s supervision layers that gave up
  (`ThinkingCap.Runtime.resume/1`): a deployment starts their modules
  again. The E-stop stays latched: `release_estop/1` when the robot is
  safe to drive.
  """
  @spec resume(atom()) :: %{node() => [atom()]}
  def resume(robot) do
    resumed = Runtime.resume(robot)

    if resumed == %{},
      do: IO.puts("#{robot}: no layer had given up"),
      else:
        for(
          {node, names} <- resumed,
          do: IO.puts("#{robot}: layers resumed on #{node}: #{Enum.join(names, ", ")}")
        )

    resumed
  end

  @doc """
  This node's view of its deployment (`ThinkingCap.Runtime.Deployment`):
  nodes up and missing, where each module runs, modules with no live node.
  """
  @spec cluster() :: Deployment.status() | :not_deployed
  def cluster do
    if Process.whereis(Deployment) do
      status = Deployment.status()
      IO.puts("robot #{status.robot}, this node #{status.logical} (#{status.node})")
      IO.puts("up: #{inspect(status.up)}  missing: #{inspect(status.missing)}")

      table(
        ["module", "runs on"],
        for({name, node} <- Enum.sort(status.modules), do: [name, node || "-- not running --"])
      )

      status
    else
      IO.puts("this node runs no deployment (modules started with ThinkingCap.Runtime.start/1)")
      :not_deployed
    end
  end

  @doc """
  The timing statistics of every periodic activity on every connected
  node (`ThinkingCap.Runtime.timing/0` per node): cycles, release jitter,
  response time, fallbacks and late results.
  """
  @spec timing() :: %{node() => %{atom() => map()}}
  def timing do
    nodes = [node() | Node.list()]

    figures =
      nodes
      |> :erpc.multicall(Runtime, :timing, [], 5_000)
      |> Enum.zip(nodes)
      |> Enum.flat_map(fn
        {{:ok, timing}, node} -> [{node, timing}]
        _ -> []
      end)
      |> Map.new()

    rows =
      for {node, activities} <- figures, {name, s} <- activities do
        [
          name,
          node,
          s.cycles,
          us(get_in(s, [:jitter_us, :mean])),
          us(get_in(s, [:jitter_us, :max])),
          us(get_in(s, [:response_us, :mean])),
          us(get_in(s, [:response_us, :max])),
          s[:fallbacks],
          s[:late]
        ]
      end

    table(
      ~w(activity node cycles jitter_mean jitter_max response_mean response_max fallbacks late),
      rows
    )

    figures
  end

  @doc "Moves a module to another node of the deployment (`ThinkingCap.Runtime.Deployment.move/2`)."
  @spec move(atom(), atom()) :: :ok | {:error, term()}
  def move(name, node), do: Deployment.move(name, node)

  @doc """
  The params of running module `name` (or `{robot, name}`): each with its
  value, type and whether it can be set while the module runs (live
  parameters, `ThinkingCap.Module`). Returns the values.
  """
  @spec params(Runtime.module_ref()) :: map() | {:error, String.t()}
  def params(name) do
    case Runtime.describe_params(name) do
      {:ok, info} ->
        IO.puts(
          "#{info.name} (#{inspect(info.module)}, robot #{info.robot})" <>
            if(info.live, do: "", else: ": takes no live changes")
        )

        table(
          ["param", "value", "type", "live", "meaning"],
          for f <- info.fields do
            [f.key, inspect(f.value), f.type, if(f.read_only, do: "no", else: "yes"), f.doc]
          end
        )

        info.values

      {:error, message} ->
        IO.puts(message)
        {:error, message}
    end
  end

  @doc """
  Sets param `key` of running module `name` (or `{robot, name}`) to
  `value` (`ThinkingCap.Runtime.set_param/4`, `by: :console`): checked
  against the module's schema, refused with the reason (the range, the
  type, read-only).
  """
  @spec param(Runtime.module_ref(), atom(), term()) :: :ok | {:error, String.t()}
  def param(name, key, value) do
    case Runtime.set_param(name, key, value, by: :console) do
      :ok ->
        IO.puts("#{format_ref(name)}.#{key} = #{inspect(value)}")

      {:error, message} ->
        IO.puts("refused: #{message}")
        {:error, message}
    end
  end

  defp format_ref({robot, name}), do: "#{robot}/#{name}"
  defp format_ref(name), do: to_string(name)

  @doc "Prints the tuples matching `template` (all by default), at most `limit`; returns the count."
  @spec tuples(Blackboard.template() | :all, pos_integer()) :: non_neg_integer()
  defdelegate tuples(template \\ :all, limit \\ 50), to: ThinkingCap.Blackboard.IEx, as: :bb_ls

  defp us(nil), do: "-"
  defp us(value), do: "#{Float.round(value / 1, 1)} µs"

  defp table(header, rows) do
    rows = Enum.map(rows, fn row -> Enum.map(row, &cell/1) end)

    widths =
      Enum.reduce([header | rows], List.duplicate(0, length(header)), fn row, widths ->
        Enum.zip_with(row, widths, &max(String.length(to_string(&1)), &2))
      end)

    for row <- [header | rows] do
      row
      |> Enum.zip(widths)
      |> Enum.map_join("  ", fn {cell, width} -> String.pad_trailing(to_string(cell), width) end)
      |> String.trim_trailing()
      |> IO.puts()
    end

    :ok
  end

  defp cell(value) when is_binary(value), do: value
  defp cell(nil), do: "-"
  defp cell(value) when is_atom(value), do: Atom.to_string(value)
  defp cell(value), do: to_string(value)
end
