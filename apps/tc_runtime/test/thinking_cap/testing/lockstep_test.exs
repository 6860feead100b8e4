defmodule ThinkingCap.Testing.LockstepTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.Testing.Lockstep
  alias ThinkingCap.Test.Modules

  defp lock do
    Lockstep.new(
      robot: :r1,
      modules: [
        cruise: {Modules.Cruise, [speed: 0.4], period: 0.1},
        echo: {Modules.Echo, [], subscribe: [{:ping, :_, :_}]},
        slow: {Modules.Slow, [sleep_ms: 0], period: 0.5}
      ]
    )
  end

  test "init actions are written; subscribers run on delivered tuples" do
    lock = lock()
    assert {:started, :r1, %{name: :cruise}} = Lockstep.latest(lock, {:started, :r1, :_})
    lock = Lockstep.deliver(lock, {:ping, :r1, 7})
    assert {:pong, :r1, 7} = Lockstep.latest(lock, {:pong, :r1, :_})
    assert {:pong, :r1, 7} in Lockstep.outs(lock)
  end

  test "periodic modules are released by the simulated clock, each at its period" do
    lock = lock() |> Lockstep.advance(1.0)
    # releases at 0.0, 0.1, ..., 1.0 and at 0.0, 0.5, 1.0
    assert Lockstep.state(lock, :cruise) == %{speed: 0.4}
    assert lock.modules.cruise.cycle == 11
    assert lock.modules.slow.cycle == 3
    assert lock |> Lockstep.advance(1.05) |> then(& &1.modules.cruise.cycle) == 11
  end

  defmodule Applier do
    @moduledoc false
    use ThinkingCap.Module
    @impl true
    def init(_params, ctx), do: {:ok, ctx.robot}
    @impl true
    def handle_cycle(release, robot), do: {[command: {:go, release.cycle}], robot}
    @impl true
    def handle_applied(%{kind: kind, command: command}, robot),
      do: {[out: {:applied, robot, {kind, command}}], robot}
  end

  test "a cycle's command comes back to the module as applied" do
    lock = Lockstep.new(robot: :r2, modules: [a: {Applier, [], period: 0.1}])
    lock = Lockstep.advance(lock, 0.25)
    assert Lockstep.latest(lock, {:applied, :r2, :_}) == {:applied, :r2, {:fresh, {:go, 2}}}
  end
end
