defmodule ThinkingCap.Config.Error do
  @moduledoc """
  One problem in a description file, printed as `file:line:column: message`
  (line and column are 1-based; 0 when the problem concerns a whole file).
  """

  @enforce_keys [:file, :line, :column, :message]
  defstruct [:file, :line, :column, :message]

  @type t :: %__MODULE__{
          file: Path.t(),
          line: non_neg_integer(),
          column: non_neg_integer(),
          message: String.t()
        }

  @doc "Builds an error at `{line, column}` of `file`."
  @spec new(Path.t(), {non_neg_integer(), non_neg_integer()}, String.t()) :: t()
  def new(file, {line, column}, message),
    do: %__MODULE__{file: file, line: line, column: column, message: message}

  defimpl String.Chars do
    def to_string(%{file: file, line: line, column: column, message: message}),
      do: "#{file}:#{line}:#{column}: #{message}"
  end
end
