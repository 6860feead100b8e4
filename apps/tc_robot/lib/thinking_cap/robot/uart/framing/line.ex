defmodule ThinkingCap.Robot.UART.Framing.Line do
  @moduledoc """
  Lines: each frame received is the bytes before a separator (not
  included); each write gets the separator appended.

  Options (`framing: {#{inspect(__MODULE__)}, opts}`):

    * `separator:` a non-empty binary, default `"\\n"` (`"\\r\\n"` works:
      a separator split across two reads is still found);
    * `max_length:` bytes, default 4096. A line longer than that (complete
      or still unfinished) is delivered as `{:partial, data}` and dropped
      from the buffer, so a line without an end cannot grow without bound.

  `framing: #{inspect(__MODULE__)}` takes the defaults.
  """
  @behaviour ThinkingCap.Robot.UART.Framing

  @enforce_keys [:separator, :max_length]
  defstruct separator: "\n", max_length: 4096, buffer: <<>>

  @type t :: %__MODULE__{separator: binary(), max_length: pos_integer(), buffer: binary()}

  @impl true
  @spec init(keyword() | term()) :: {:ok, t()} | {:error, term()}
  def init(opts) when is_list(opts) do
    separator = Keyword.get(opts, :separator, "\n")
    max_length = Keyword.get(opts, :max_length, 4096)

    cond do
      not (is_binary(separator) and separator != "") ->
        {:error, {:bad_option, :separator, separator}}

      not (is_integer(max_length) and max_length > 0) ->
        {:error, {:bad_option, :max_length, max_length}}

      true ->
        {:ok, %__MODULE__{separator: separator, max_length: max_length}}
    end
  end

  def init(other), do: {:error, {:bad_option, :framing_args, other}}

  @impl true
  @spec add_framing(iodata(), t()) :: {:ok, iodata(), t()}
  def add_framing(data, state), do: {:ok, [data, state.separator], state}

  @impl true
  @spec remove_framing(binary(), t()) :: {:in_frame | :ok, [binary() | {:partial, binary()}], t()}
  def remove_framing(data, state) do
    {frames, rest} = split(state.buffer <> data, state, [])

    {frames, rest} =
      if byte_size(rest) > state.max_length,
        do: {frames ++ [{:partial, rest}], <<>>},
        else: {frames, rest}

    {if(rest == <<>>, do: :ok, else: :in_frame), frames, %{state | buffer: rest}}
  end

  defp split(buffer, state, acc) do
    case :binary.split(buffer, state.separator) do
      [line, rest] -> split(rest, state, [line_frame(line, state) | acc])
      [rest] -> {Enum.reverse(acc), rest}
    end
  end

  defp line_frame(line, state) when byte_size(line) > state.max_length, do: {:partial, line}
  defp line_frame(line, _state), do: line

  @impl true
  @spec frame_timeout(t()) :: {:ok, [binary()], t()}
  def frame_timeout(%{buffer: <<>>} = state), do: {:ok, [], state}
  def frame_timeout(state), do: {:ok, [state.buffer], %{state | buffer: <<>>}}

  @impl true
  @spec flush(:receive | :transmit | :both, t()) :: t()
  def flush(:transmit, state), do: state
  def flush(_direction, state), do: %{state | buffer: <<>>}
end
