defmodule ThinkingCap.Robot.UART.Framing do
  @moduledoc """
  How a `ThinkingCap.Robot.UART` cuts the bytes of a serial line into
  frames, and wraps what it writes.

  A framing module's state lives in the UART process. `add_framing/2` is
  applied to everything written; `remove_framing/2` to every chunk of
  bytes received, returning the complete frames found so far and
  `:in_frame` while bytes of an unfinished frame are buffered (the UART
  then starts its `rx_framing_timeout`, and calls `frame_timeout/1` when it
  expires: the partial frames it returns reach the owner as
  `{:partial, binary}`). A frame may itself be `{:partial, binary}` (a
  framing that gives up on an over-long frame delivers it so).
  `flush/2` forgets buffered bytes of the direction flushed.

  Shipped: `ThinkingCap.Robot.UART.Framing.None` (bytes as they come) and
  `ThinkingCap.Robot.UART.Framing.Line` (lines ending in a separator).
  """

  @type state :: term()
  @type frame :: binary() | {:partial, binary()} | term()

  @doc "Makes the framing's state from the `args` of `framing: {module, args}`."
  @callback init(args :: term()) :: {:ok, state()} | {:error, term()}

  @doc "Wraps data about to be written."
  @callback add_framing(iodata(), state()) :: {:ok, iodata(), state()}

  @doc """
  Takes received bytes; returns the complete frames, and `:in_frame` when
  bytes of an unfinished frame are buffered (`:ok` when none are).
  """
  @callback remove_framing(binary(), state()) :: {:in_frame | :ok, [frame()], state()}

  @doc "The receive timeout expired: returns what was buffered (partial frames) and clears it."
  @callback frame_timeout(state()) :: {:ok, [binary()], state()}

  @doc "Forgets buffered data of `direction`."
  @callback flush(direction :: :receive | :transmit | :both, state()) :: state()
end
