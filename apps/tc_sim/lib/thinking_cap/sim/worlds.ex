defmodule ThinkingCap.Sim.Worlds do
  @moduledoc """
  The simulations running on this node, one per world (WDF path), started
  on first use under the simulator's supervisor, so that every simulated
  robot of a world shares its simulation.
  """

  @registry ThinkingCap.Sim.Registry

  @doc """
  The simulation of the WDF at `path`, started in real-time mode with
  `opts` (see `ThinkingCap.Sim.start_link/1`) if it is not running.
  """
  @spec ensure(Path.t(), keyword()) :: {:ok, pid()} | {:error, String.t()}
  def ensure(path, opts \\ []) do
    path = Path.expand(path)

    case lookup(path) do
      {:ok, pid} ->
        {:ok, pid}

      :error ->
        spec = %{
          id: path,
          start:
            {ThinkingCap.Sim, :start_link,
             [Keyword.merge([mode: :realtime], opts) ++ [world: path, name: via(path)]]},
          restart: :transient
        }

        case DynamicSupervisor.start_child(ThinkingCap.Sim.Supervisor, spec) do
          {:ok, pid} -> {:ok, pid}
          {:error, {:already_started, pid}} -> {:ok, pid}
          {:error, {message, _}} when is_binary(message) -> {:error, message}
          {:error, message} when is_binary(message) -> {:error, message}
          {:error, reason} -> {:error, "#{path}: #{inspect(reason)}"}
        end
    end
  end

  @doc "The running simulation of a WDF path, if any."
  @spec lookup(Path.t()) :: {:ok, pid()} | :error
  def lookup(path) do
    case Registry.lookup(@registry, Path.expand(path)) do
      [{pid, _}] -> {:ok, pid}
      [] -> :error
    end
  end

  @doc "Every running simulation, by WDF path."
  @spec all() :: [{Path.t(), pid()}]
  def all, do: Registry.select(@registry, [{{:"$1", :"$2", :_}, [], [{{:"$1", :"$2"}}]}])

  defp via(path), do: {:via, Registry, {@registry, path}}
end
