defmodule ThinkingCap.Robot.UART.Framing.None do
  @moduledoc """
  No framing: every chunk of bytes the line receives is delivered as it
  comes, and writes go out unchanged. The default framing of
  `ThinkingCap.Robot.UART`.
  """
  @behaviour ThinkingCap.Robot.UART.Framing

  @impl true
  @spec init(term()) :: {:ok, nil}
  def init(_args), do: {:ok, nil}

  @impl true
  @spec add_framing(iodata(), nil) :: {:ok, iodata(), nil}
  def add_framing(data, state), do: {:ok, data, state}

  @impl true
  @spec remove_framing(binary(), nil) :: {:ok, [binary()], nil}
  def remove_framing(<<>>, state), do: {:ok, [], state}
  def remove_framing(data, state), do: {:ok, [data], state}

  @impl true
  @spec frame_timeout(nil) :: {:ok, [], nil}
  def frame_timeout(state), do: {:ok, [], state}

  @impl true
  @spec flush(:receive | :transmit | :both, nil) :: nil
  def flush(_direction, state), do: state
end
