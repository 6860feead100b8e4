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
end
