defmodule ThinkingCap.Test.Modules do
  @moduledoc false
  # Modules the runtime tests host (compiled for peer nodes too).

  defmodule Cruise do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def init(params, ctx),
      do:
        {[out: {:started, ctx.robot, %{name: ctx.name, node: ctx.node}}],
         %{speed: params[:speed] || 0.2}}

    @impl true
    def handle_cycle(release, state), do: {[command: {:vel, state.speed, release.cycle}], state}
  end

  defmodule Punctual do
    @moduledoc false
    # tells its owner, each cycle, when handle_cycle/2 started and when the
    # release left the worker, both against the instant it was due (ns)
    use ThinkingCap.Module
    @impl true
    def init(params, _ctx), do: {:ok, params[:report_to]}
    @impl true
    def handle_cycle(release, to) do
      started = ThinkingCap.Cycle.Clock.now_ns()

      send(
        to,
        {:punctual, started - release.scheduled_ns, release.released_ns - release.scheduled_ns}
      )

      {[command: :on_time], to}
    end
  end

  defmodule Wired do
    @moduledoc false
    # hands its device's command path to the timing worker
    use ThinkingCap.Module
    @impl true
    def init(params, _ctx), do: {[{:attach_wire, params[:device], "stop\n"}], nil}

    @impl true
    def handle_cycle(release, state),
      do: {[command: {:n, release.cycle}, wire: ["n ", "#{release.cycle}", ?\n]], state}
  end

  defmodule CruiseV2 do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def handle_swap(Cruise, old_state, _ctx), do: {:ok, Map.put(old_state, :v2, true)}
    @impl true
    def handle_cycle(release, state), do: {[command: {:vel2, state.speed, release.cycle}], state}
  end

  defmodule Slow do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def init(params, ctx), do: {:ok, %{ms: params[:sleep_ms], robot: ctx.robot}}
    @impl true
    def handle_cycle(_release, state) do
      Process.sleep(state.ms)
      {[command: :slow_result], state}
    end

    # what a driver does: act on the applied command, fresh or fallback
    @impl true
    def handle_applied(%{kind: :fallback, command: command}, state),
      do: {[out: {{:applied, state.robot, command}, [key: {:applied, state.robot}]}], state}

    def handle_applied(_applied, state), do: {[], state}
  end

  defmodule Crashy do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def handle_cycle(release, state), do: {[command: {:ok, release.cycle}], state}
    @impl true
    def handle_tuple({:crash, _robot}, _state), do: raise("asked to crash")
  end

  defmodule Broken do
    @moduledoc false
    # a periodic module that crashes at every release: a crash loop
    use ThinkingCap.Module
    @impl true
    def handle_cycle(_release, _state), do: raise("broken sensor")
  end

  defmodule Parting do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def init(_params, ctx), do: {:ok, %{robot: ctx.robot}}
    @impl true
    def terminate(reason, state),
      do: ThinkingCap.Blackboard.out({:parted, state.robot, %{reason: reason, pid: self()}})
  end

  defmodule Echo do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def handle_tuple({:ping, robot, n}, state), do: {[out: {:pong, robot, n}], state}
  end

  defmodule Counter do
    @moduledoc false
    # counts its cycles, carrying the count over a failover by handoff/1
    use ThinkingCap.Module
    @impl true
    def init(_params, ctx) do
      from = if ctx.handoff, do: ctx.handoff.n
      {:ok, %{robot: ctx.robot, n: from || 0, resumed_from: from}}
    end

    @impl true
    def handle_cycle(_release, state) do
      state = %{state | n: state.n + 1}
      count = %{n: state.n, resumed_from: state.resumed_from, node: node()}
      {[out: {{:count, state.robot, count}, [key: {:count, state.robot}]}], state}
    end

    @impl true
    def handoff(state), do: %{n: state.n}
  end

  defmodule Idle do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def init(_params, ctx), do: {:ok, %{robot: ctx.robot, n: 0}}
    @impl true
    def handle_background(state) do
      Process.sleep(5)
      n = state.n + 1

      {[
         out:
           {{:bg, state.robot, %{n: n, priority: Process.info(self(), :priority)}},
            [key: {:bg, state.robot}]}
       ], %{state | n: n}}
    end
  end

  defmodule Tunable do
    @moduledoc false
    # declares params and takes live changes of them
    use ThinkingCap.Module

    @impl true
    def params do
      [
        speed: {{:number_range, 0.0, 1.0}, default: 0.2, doc: "m/s"},
        gain: {:pos_number, default: 1.0, doc: "refused above 5 by the module"},
        mode: {{:one_of, [:slow, :fast]}, default: :slow, doc: "a choice"},
        enabled: {:boolean, default: true, doc: "a flag"},
        seed: {:integer, default: 1, read_only: true, doc: "read at start"}
      ]
    end

    @impl true
    def init(_params, ctx), do: {:ok, %{robot: ctx.robot, speed: ctx.params.speed, seen: []}}

    @impl true
    def handle_cycle(release, state), do: {[command: {:vel, state.speed, release.cycle}], state}

    @impl true
    def handle_param(:gain, gain, state) when gain > 5,
      do: {:error, "a gain above 5 makes it oscillate", %{state | seen: :spoilt}}

    def handle_param(:speed, speed, state),
      do:
        {[out: {{:tuned, state.robot, speed}, [key: {:tuned, state.robot}]}],
         %{state | speed: speed, seen: [{:speed, speed} | state.seen]}}

    def handle_param(key, value, state), do: {[], %{state | seen: [{key, value} | state.seen]}}
  end

  defmodule Declared do
    @moduledoc false
    # declares params but takes no live changes (no handle_param/3)
    use ThinkingCap.Module

    @impl true
    def params, do: [speed: {{:number_range, 0.0, 1.0}, default: 0.2, doc: "m/s"}]
  end

  defmodule Scripted do
    @moduledoc false
    # does what the tuples it is sent say: the same module for the runtime
    # and the lockstep harness
    use ThinkingCap.Module

    @impl true
    def params, do: [level: {{:int_range, 0, 100}, default: 0, doc: "set by itself"}]

    @impl true
    def init(_params, ctx) do
      r = ctx.robot

      {[
         {:subscribe, {:poke, r, :_}},
         {:subscribe, {:bad, r, :_}},
         {:out, {{:ready, r, ctx.params.level}, [key: {:ready, r}]}}
       ], %{robot: r, level: ctx.params.level}}
    end

    @impl true
    def handle_tuple({:poke, r, n}, state) do
      {[
         {:out, {:poked, r, n}},
         # counts for nothing outside handle_cycle/2 (a warning)
         {:command, :ignored},
         {:subscribe, {:second, r, :_}},
         {:set_param, :level, n}
       ], %{state | level: n}}
    end

    def handle_tuple({:second, r, n}, state),
      do: {[out: {:second_seen, r, {n, state.level}}], state}

    def handle_tuple({:bad, _r, action}, state), do: {[action], state}

    @impl true
    def handle_cycle(_release, state), do: {[command: {:level, state.level}], state}

    @impl true
    def handle_applied(%{kind: :fresh, command: command}, state),
      do: {[out: {{:applied, state.robot, command}, [key: {:applied, state.robot}]}], state}

    def handle_applied(_applied, state), do: {[], state}
  end

  defmodule Traced do
    @moduledoc false
    # sums the ticks it is sent, times a live gain; crashes when asked
    use ThinkingCap.Module

    @impl true
    def params, do: [gain: {{:number_range, 0.0, 10.0}, default: 1.0, doc: "times each tick"}]

    @impl true
    def init(params, ctx),
      do:
        {[subscribe: {:tick, ctx.robot, :_}],
         %{robot: ctx.robot, gain: params[:gain] || 1.0, sum: 0.0}}

    @impl true
    def handle_tuple({:tick, _robot, %{n: :crash}}, _state), do: raise("asked to crash")

    def handle_tuple({:tick, robot, %{n: n}}, state) do
      sum = state.sum + n * state.gain
      {[out: {{:sum, robot, %{sum: sum}}, [key: {:sum, robot}]}], %{state | sum: sum}}
    end

    @impl true
    def handle_param(:gain, gain, state), do: {[], %{state | gain: gain}}

    @impl true
    def handle_cycle(_release, state), do: {[command: {:sum, state.sum}], state}
  end

  defmodule Untraced do
    @moduledoc false
    # what a driver says: its callbacks are not traced
    use ThinkingCap.Module

    @impl true
    def replay, do: [trace: false]

    @impl true
    def init(_params, ctx), do: {[subscribe: {:tick, ctx.robot, :_}], nil}
  end
end
