defmodule ThinkingCap.Runtime.Supervision.Robot do
  @moduledoc false
  # One robot's modules on this node (ThinkingCap.Runtime.Supervision):
  # a layer supervisor per layer, each a temporary child (a layer that
  # gave up stays down), then the warden that watches them. The warden
  # comes last, so it is stopped first when the robot's supervisor stops:
  # a layer it sees go is a layer that gave up.
  use Supervisor

  alias ThinkingCap.Runtime.Supervision
  alias ThinkingCap.Runtime.Supervision.Warden

  @spec start_link(atom()) :: Supervisor.on_start()
  def start_link(robot),
    do: Supervisor.start_link(__MODULE__, robot, name: Supervision.via({:robot, robot}))

  def child_spec(robot),
    do: %{
      id: {__MODULE__, robot},
      start: {__MODULE__, :start_link, [robot]},
      type: :supervisor,
      # its layers give up on their own; the robot's supervisor is not
      # started again behind the warden's back
      restart: :temporary
    }

  @impl true
  def init(robot) do
    layers = for layer <- Supervision.layer_names(), do: layer_spec(robot, layer)
    Supervisor.init(layers ++ [{Warden, robot}], strategy: :one_for_one)
  end

  @doc false
  # The child spec of `robot`'s layer `layer`: a DynamicSupervisor of
  # module hosts with the layer's restart intensity.
  def layer_spec(robot, layer) do
    {max_restarts, max_seconds} = Keyword.fetch!(Supervision.layers(), layer)

    %{
      id: {:layer, layer},
      start:
        {DynamicSupervisor, :start_link,
         [
           [
             strategy: :one_for_one,
             max_restarts: max_restarts,
             max_seconds: max_seconds,
             name: Supervision.via({:layer, robot, layer})
           ]
         ]},
      type: :supervisor,
      restart: :temporary
    }
  end
end
