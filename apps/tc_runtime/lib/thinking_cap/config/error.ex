defmodule ThinkingCap.Config.Error do
  @moduledoc """
  One problem in a description file, a map or a URDF, printed as
  `file:line:column: message` (line and column are 1-based; 0 when the
  problem concerns a whole file), or, in a binary file (a PGM image), as
  `file:byte OFFSET: message` (`offset` 0-based).
  """

  @enforce_keys [:file, :line, :column, :message]
  defstruct [:file, :line, :column, :message, offset: nil]

  @type t :: %__MODULE__{
          file: Path.t(),
          line: non_neg_integer(),
          column: non_neg_integer(),
          message: String.t(),
          offset: non_neg_integer() | nil
        }

  @max_errors 50

  @doc "Builds an error at `{line, column}` of `file`."
  @spec new(Path.t(), {non_neg_integer(), non_neg_integer()}, String.t()) :: t()
  def new(file, {line, column}, message),
    do: %__MODULE__{file: file, line: line, column: column, message: message}

  @doc "Builds an error at byte `offset` (0-based) of the binary file `file`."
  @spec at_byte(Path.t(), non_neg_integer(), String.t()) :: t()
  def at_byte(file, offset, message),
    do: %__MODULE__{file: file, line: 0, column: 0, offset: offset, message: message}

  @doc """
  At most #{@max_errors} errors, then one more that says how many were left
  out (`and N more errors`, at the place of the first one left out).
  """
  @spec cap([t()]) :: [t()]
  def cap(errors) do
    case Enum.split(errors, @max_errors) do
      {some, []} ->
        some

      {some, [first | _] = rest} ->
        some ++ [%{first | message: "and #{length(rest)} more errors"}]
    end
  end

  defimpl String.Chars do
    def to_string(%{file: file, offset: offset, message: message}) when is_integer(offset),
      do: "#{file}:byte #{offset}: #{message}"

    def to_string(%{file: file, line: line, column: column, message: message}),
      do: "#{file}:#{line}:#{column}: #{message}"
  end
end
