defmodule ThinkingCap.BlackBox.Core.Options do
  @moduledoc false
  # Options of the black box's processes, checked with the description
  # files' schema language: nested under `name`, so that the messages
  # name them ("recorder.dir: ...").

  alias ThinkingCap.Config.Schema

  @spec validate(term(), atom(), Schema.fields(), String.t()) ::
          {:ok, map()} | {:error, String.t()}
  def validate(opts, name, fields, label) when is_list(opts) do
    case Schema.validate(
           [{name, opts}],
           {:keyword, [{name, {{:keyword, fields}, required: true}}]},
           label,
           %{}
         ) do
      {%{^name => value}, []} -> {:ok, value}
      {_value, errors} -> {:error, Enum.map_join(errors, "; ", & &1.message)}
    end
  end

  def validate(other, _name, _fields, label),
    do: {:error, "#{label}: expected a keyword list, got #{inspect(other)}"}

  # A robot's process under a supervisor: one per robot, started again
  # only after a crash, given 5 s to close its files.
  @spec child_spec(module(), keyword()) :: Supervisor.child_spec()
  def child_spec(module, opts),
    do: %{
      id: {module, opts[:robot]},
      start: {module, :start_link, [opts]},
      restart: :transient,
      shutdown: 5_000
    }
end
