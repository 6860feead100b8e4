defmodule ThinkingCap.Config.ADF do
  # the keys only a deployment needs; the dashboard's own options are
  # defined once, in Config.DashboardOptions
  @dashboard_deployment_fields [
    enabled: {:boolean, default: false, doc: "serve the web dashboard"},
    node:
      {:atom,
       default: :local,
       doc:
         "the logical node serving it in a deployment (`:local`: the first of `nodes`); `ThinkingCap.Runtime.start/1` serves it on the starting node"}
  ]
  @dashboard_fields @dashboard_deployment_fields ++ ThinkingCap.Config.DashboardOptions.fields()

  # also the options of ThinkingCap.BlackBox.Recorder (tc_blackbox), which
  # validates them with this same list: the runtime only checks them
  @record_fields [
    enabled:
      {:boolean,
       default: false,
       doc:
         "record the robot's tuples into MCAP files (`ThinkingCap.BlackBox.Recorder`, started by the node that starts the ADF)"},
    dir:
      {:path,
       default: "recordings",
       doc: "the directory of the files; a relative one is taken from the working directory"},
    compression:
      {{:one_of, [:zstd, :lz4, :none]},
       default: :zstd, doc: "the chunks' compression (zstd: smallest; lz4: fastest)"},
    chunk_bytes:
      {{:int_range, 4_096, 67_108_864},
       default: 1_048_576, doc: "a chunk is closed when it holds this many bytes (uncompressed)"},
    chunk_seconds:
      {{:number_range, 0.01, 60},
       default: 1.0,
       doc: "and at the latest this many seconds after it opened: a crash loses at most that much"},
    file_bytes:
      {{:int_range, 65_536, 1_099_511_627_776},
       default: 268_435_456, doc: "a file is closed and the next begun past this many bytes"},
    file_seconds:
      {{:number_range, 1, 86_400},
       default: 600.0, doc: "and at the latest this many seconds after it was begun"},
    templates:
      {{:list, :template},
       default: [],
       doc:
         "the blackboard templates recorded; empty: every tuple of the robot, `{:_, robot, :_}`"},
    replay:
      {:boolean,
       default: true,
       doc:
         "keep each tuple whole too and trace the robot's modules, so that the recording replays (`mix tc.replay`); false: Foxglove's messages only, about half the bytes"}
  ]

  # also the options of ThinkingCap.BlackBox.RingBuffer (tc_blackbox),
  # which validates them with this same list: the runtime only checks them
  @black_box_fields [
    enabled:
      {:boolean,
       doc:
         "keep the robot's last `seconds` in memory and dump them to an MCAP file on an incident (`ThinkingCap.BlackBox.RingBuffer`, started by the node that starts the ADF); unset: on wherever the black-box app runs, unless its `:black_box_by_default` env is false"},
    seconds:
      {{:number_range, 1, 3_600},
       default: 60.0, doc: "the seconds kept, and dumped before a trigger"},
    after:
      {{:number_range, 0, 600},
       default: 5.0, doc: "the seconds a dump goes on after its (last) trigger"},
    dir:
      {:path,
       default: "black_box",
       doc: "the directory of the dumps; a relative one is taken from the working directory"},
    max_bytes:
      {{:int_range, 65_536, 17_179_869_184},
       default: 268_435_456,
       doc: "the most bytes kept (the tuples' external size): the oldest go first past it"},
    max_messages:
      {{:int_range, 100, 100_000_000},
       default: 500_000, doc: "the most tuples kept: the oldest go first past it"},
    misses:
      {{:int_range, 1, 1_000_000},
       default: 5,
       doc:
         "a dump when this many deadline misses of the robot's periodic modules come in a streak (each `:timing` summary with a new miss, none without)"},
    compression:
      {{:one_of, [:zstd, :lz4, :none]}, default: :zstd, doc: "the dumps' chunk compression"}
  ]

  @module_fields [
    module: {:module, required: true, doc: "the Elixir module implementing it"},
    node:
      {:atom,
       default: :local,
       doc:
         "the logical node (a key of `nodes`) it runs on; `:local`: the node that reads the ADF"},
    standby: {{:list, :atom}, default: [], doc: "logical nodes it fails over to, in order"},
    failback:
      {{:one_of, [:manual, :auto]},
       default: :manual,
       doc:
         "after a failover: `:manual` stays on the standby until moved (`ThinkingCap.Runtime.Deployment.move/2`); `:auto` goes back to the first live node of `[node | standby]`"},
    handoff_every:
      {:pos_number,
       default: 1.0,
       doc:
         "seconds between the handoffs (`c:ThinkingCap.Module.handoff/1`) sent to the other nodes of `[node | standby]`"},
    activity:
      {{:one_of, [:periodic, :event, :background]}, required: true, doc: "how it is released"},
    layer:
      {{:one_of, [:reactive, :cognitive]},
       doc:
         "its supervision layer, with that layer's restart intensity (`ThinkingCap.Runtime.Supervision`): `:reactive` (base, perception, control; 5 restarts in 5 s) or `:cognitive` (localization, mapping, planning; 10 in 60 s). Default: `:reactive` for periodic modules, `:cognitive` for the others"},
    period: {:pos_number, doc: "seconds between releases (periodic only; required there)"},
    deadline:
      {:pos_number,
       doc:
         "seconds after a release by which the result is due (periodic only; default: the period)"},
    lead:
      {{:number_range, 0.0, 0.005},
       default: 0.0,
       doc:
         "seconds early (at most 5 ms: it is spent spinning) the timing worker releases it; the host then waits, busy, for the scheduled instant, so `handle_cycle/2` starts on time whatever the delivery took (periodic only; `ThinkingCap.Cycle`'s Lead; deadline + lead at most the period)"},
    priority:
      {{:int_range, 1, 99}, default: 50, doc: "periodic releases of higher priority go first"},
    fallback:
      {:any, default: :stop, doc: "the command applied when a result misses its deadline"},
    subscribe:
      {{:list, :template}, default: [], doc: "blackboard templates whose tuples it handles"},
    params: {:params, default: [], doc: "passed to the module's `init/2`"}
  ]

  @cluster_fields [
    connect_every:
      {:pos_number, default: 1.0, doc: "seconds between attempts to connect to missing nodes"},
    settle:
      {:non_neg_number,
       default: 3.0,
       doc:
         "seconds a starting node waits for the other nodes before it takes over modules whose nodes are missing"}
  ]

  @fields [
    robot:
      {:atom,
       required: true, doc: "the robot's id in blackboard tuples (`{tag, robot, payload}`)"},
    rdf: {:path, doc: "the robot description file, relative to this file"},
    wdf: {:path, doc: "the world description file, relative to this file"},
    nodes:
      {{:keyword_of, :atom},
       default: [], doc: "`logical_name: :\"name@host\"`; empty: everything on one node"},
    cluster:
      {{:keyword, @cluster_fields},
       default: [], doc: "how a deployment's nodes find each other (below)"},
    dashboard:
      {{:keyword, @dashboard_fields}, default: [], doc: "web dashboard settings (below)"},
    record:
      {{:keyword, @record_fields},
       default: [], doc: "recording the robot's tuples to MCAP files (below)"},
    black_box:
      {{:keyword, @black_box_fields},
       default: [], doc: "the black box: the last seconds, dumped on incidents (below)"},
    modules:
      {{:keyword_of, {:keyword, @module_fields}},
       required: true, doc: "`name: [module keys]` (below)"}
  ]

  @moduledoc """
  The architecture description file (`*.adf`): which modules run, the
  module implementing each (`module: ThinkingCap.Sim.Robot` or a real
  robot's driver is the whole switch between simulation and hardware), on
  which node, with which activity and timing, with which parameters; the
  nodes of the cluster; the dashboard.

      [
        robot: :r1,
        rdf: "office_robot.rdf",
        wdf: "office.wdf",
        nodes: [main: :"tc_main@127.0.0.1"],
        modules: [
          base: [module: ThinkingCap.Sim.Robot, node: :main, activity: :periodic, period: 0.01, deadline: 0.003, priority: 90]
        ]
      ]

  Times are in seconds.

  ## Top-level keys

  #{ThinkingCap.Config.Schema.describe(@fields)}

  ## Module keys

  #{ThinkingCap.Config.Schema.describe(@module_fields)}

  ## Cluster keys

  #{ThinkingCap.Config.Schema.describe(@cluster_fields)}

  ## Dashboard keys

  #{ThinkingCap.Config.Schema.describe(@dashboard_fields)}

  ## Record keys

  The runtime only checks them: the recorder is in `tc_blackbox`, above
  the runtime, which starts one for the robot when the ADF it announces
  (`{:adf, robot, %{record: ...}}`) enables it.

  #{ThinkingCap.Config.Schema.describe(@record_fields)}

  ## Black-box keys

  Checked here too; the ring buffer is in `tc_blackbox`, which starts it
  from the announcement (`{:adf, robot, %{black_box: ...}}`).

  #{ThinkingCap.Config.Schema.describe(@black_box_fields)}
  """

  alias ThinkingCap.Config.Schema

  defstruct [
    :file,
    :robot,
    :rdf,
    :wdf,
    nodes: %{},
    cluster: %{},
    dashboard: %{},
    record: %{},
    black_box: %{},
    modules: []
  ]

  @typedoc """
  One module entry, with defaults filled in (`deadline` defaults to
  `period`, `layer` follows from `activity`).
  """
  @type module_spec :: %{
          name: atom(),
          module: module(),
          node: atom(),
          standby: [atom()],
          failback: :manual | :auto,
          handoff_every: float(),
          activity: :periodic | :event | :background,
          layer: :reactive | :cognitive,
          period: float() | nil,
          deadline: float() | nil,
          lead: float(),
          priority: 1..99,
          fallback: term(),
          subscribe: [tuple()],
          params: keyword() | map()
        }

  @type t :: %__MODULE__{
          file: Path.t(),
          robot: atom(),
          rdf: Path.t() | nil,
          wdf: Path.t() | nil,
          nodes: %{atom() => node()},
          cluster: %{connect_every: float(), settle: float()},
          dashboard: map(),
          record: map(),
          black_box: map(),
          modules: [module_spec()]
        }

  @doc """
  The `record:` section's fields (a `ThinkingCap.Config.Schema`): the
  recorder validates its options with them too.
  """
  @spec record_fields() :: Schema.fields()
  def record_fields, do: @record_fields

  @doc """
  The `black_box:` section's fields (a `ThinkingCap.Config.Schema`): the
  ring buffer validates its options with them too.
  """
  @spec black_box_fields() :: Schema.fields()
  def black_box_fields, do: @black_box_fields

  @doc false
  # Validates the data of an ADF read from `file`.
  @spec from_data(term(), Path.t(), map()) ::
          {:ok, t()} | {:error, [ThinkingCap.Config.Error.t()]}
  def from_data(data, file, positions) do
    {value, st} = Schema.start(data, @fields, file, positions)
    modules = for {name, spec} <- value[:modules] || [], do: Map.put(spec, :name, name)
    st = Map.put(st, :places, places(modules, value[:wdf], file))
    nodes = value[:nodes] || []

    st =
      st
      |> check_nodes(nodes)
      |> check_modules(modules, Keyword.keys(nodes))
      |> check_node([:dashboard, :node], value[:dashboard][:node], Keyword.keys(nodes))
      |> check_file(:rdf, value[:rdf])
      |> check_file(:wdf, value[:wdf])

    case Schema.errors(st) do
      [] ->
        modules =
          Enum.map(modules, fn m ->
            %{
              m
              | deadline: m.deadline || m.period,
                layer: m.layer || ThinkingCap.Runtime.Supervision.default_layer(m.activity)
            }
          end)

        adf = %__MODULE__{
          file: file,
          robot: value.robot,
          rdf: resolve(file, value.rdf),
          wdf: resolve(file, value.wdf)
        }

        {:ok,
         %{
           adf
           | nodes: Map.new(nodes),
             cluster: value.cluster,
             dashboard: resolve_dashboard_node(value.dashboard, nodes),
             record: value.record,
             black_box: value.black_box,
             modules: modules
         }}

      errors ->
        {:error, errors}
    end
  end

  defp resolve_dashboard_node(%{node: :local} = dashboard, [{first, _} | _]),
    do: %{dashboard | node: first}

  defp resolve_dashboard_node(dashboard, _nodes), do: dashboard

  defp check_nodes(st, nodes) do
    Enum.reduce(nodes, st, fn {name, node}, st ->
      if is_atom(node) and String.match?(Atom.to_string(node), ~r/^[^@\s]+@[^@\s]+$/),
        do: st,
        else:
          Schema.error(
            st,
            [:nodes, name],
            "nodes.#{name}: expected a node name like :\"name@host\", got #{inspect(node)}"
          )
    end)
  end

  defp check_modules(st, modules, declared) do
    Enum.reduce(modules, st, fn m, st ->
      path = [:modules, m.name]

      st
      |> check_node(path ++ [:node], m.node, declared)
      |> then(fn st ->
        Enum.reduce(Enum.with_index(m.standby), st, fn {n, i}, st ->
          check_node(st, path ++ [:standby, i], n, declared)
        end)
      end)
      |> check_timing(path, m)
      |> check_params(path, m)
    end)
  end

  # the module's params against the schema it declares (`c:ThinkingCap.Module.params/0`)
  defp check_params(st, path, %{module: module, params: params}) when is_atom(module) do
    case declared_params(module) do
      nil ->
        st

      fields ->
        {_value, st} = Schema.check_at(st, {:keyword, fields}, params, path ++ [:params])
        st
    end
  end

  defp check_params(st, _path, _module), do: st

  @doc """
  The params schema a module declares (`c:ThinkingCap.Module.params/0`),
  or nil when it declares none (or is not loaded).
  """
  @spec declared_params(module()) :: Schema.fields() | nil
  def declared_params(module) do
    if Code.ensure_loaded?(module) and function_exported?(module, :params, 0),
      do: module.params()
  end

  # the names of the WDF's places, for params of type :place: read only
  # when a module declares params (nil when the ADF names no WDF or it
  # cannot be read: its own check reports that)
  defp places(_modules, nil, _file), do: nil

  defp places(modules, wdf, file) do
    with true <- Enum.any?(modules, &(is_atom(&1[:module]) and declared_params(&1[:module]))),
         {:ok, %ThinkingCap.Config.WDF{} = w} <- ThinkingCap.Config.read(resolve(file, wdf)) do
      MapSet.new(
        for key <- [:waypoints, :rooms, :corridors, :doors],
            item <- Map.get(w, key),
            do: item.name
      )
    else
      _ -> nil
    end
  end

  defp check_node(st, path, node, declared) do
    if node == :local or not is_atom(node) or node in declared,
      do: st,
      else: undeclared_node(st, path, node, declared)
  end

  defp undeclared_node(st, path, node, declared) do
    known =
      if declared == [],
        do: "no nodes are declared, so use :local",
        else: "declared: #{Enum.map_join(declared, ", ", &":#{&1}")}"

    Schema.error(
      st,
      path,
      "#{Schema.path_string(path)}: node :#{node} is not declared in nodes (#{known})"
    )
  end

  defp check_timing(st, path, %{activity: :periodic, period: nil}) do
    Schema.error(st, path, "#{Schema.path_string(path)}: a periodic module needs period: seconds")
  end

  defp check_timing(st, path, %{activity: :periodic, period: period, deadline: deadline})
       when is_number(period) and is_number(deadline) and deadline > period do
    Schema.error(
      st,
      path ++ [:deadline],
      "#{Schema.path_string(path)}.deadline: #{deadline} s is longer than the period #{period} s"
    )
  end

  defp check_timing(st, path, %{activity: :periodic, period: period, lead: lead} = m)
       when is_number(period) and is_number(lead) and lead > 0 do
    deadline = m.deadline || period

    if deadline + lead > period,
      do:
        Schema.error(
          st,
          path ++ [:lead],
          "#{Schema.path_string(path)}.lead: #{lead} s early with a deadline of " <>
            "#{deadline} s runs past the period #{period} s (deadline + lead <= period)"
        ),
      else: st
  end

  defp check_timing(st, path, %{activity: activity} = m) when activity in [:event, :background] do
    Enum.reduce([:period, :deadline, :lead], st, fn key, st ->
      if Map.get(m, key) not in [nil, 0, 0.0],
        do:
          Schema.error(
            st,
            path ++ [key],
            "#{Schema.path_string(path)}.#{key}: only periodic modules have a #{key} (this one is #{activity})"
          ),
        else: st
    end)
  end

  defp check_timing(st, _path, _module), do: st

  defp check_file(st, _key, nil), do: st

  defp check_file(st, key, relative) when is_binary(relative) do
    path = resolve(st.file, relative)
    if File.regular?(path), do: st, else: Schema.error(st, [key], "#{key}: no such file #{path}")
  end

  defp check_file(st, _key, _other), do: st

  defp resolve(_file, nil), do: nil
  defp resolve(file, relative), do: Path.expand(relative, Path.dirname(file))
end
