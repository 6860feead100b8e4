defmodule ThinkingCap.Robot.UART.Options do
  @moduledoc false
  # The options of open/3, open_pty/2 and configure/2: checked up front
  # (a bad one is {:error, {:bad_option, key, value}}) and the line
  # settings encoded for the worker (see the PROTOCOL of c_src/tc_uart.c).

  alias ThinkingCap.Robot.UART.Framing

  @defaults %{
    speed: 9600,
    data_bits: 8,
    parity: :none,
    stop_bits: 1,
    flow_control: :none,
    active: true,
    framing: {Framing.None, []},
    rx_framing_timeout: 0,
    rx_timestamps: false
  }

  @parity %{none: 0, even: 1, odd: 2}
  @flow %{none: 0, hardware: 1, software: 2}

  @type config :: %{
          speed: pos_integer(),
          data_bits: 5..8,
          parity: :none | :even | :odd,
          stop_bits: 1 | 2,
          flow_control: :none | :hardware | :software,
          active: boolean(),
          framing: {module(), term()},
          rx_framing_timeout: non_neg_integer(),
          rx_timestamps: boolean()
        }

  @spec defaults() :: config()
  def defaults, do: @defaults

  @doc "`opts` over `base`; `speeds` are the speeds the worker supports."
  @spec validate(term(), config(), [pos_integer()]) ::
          {:ok, config()} | {:error, {:bad_option, term(), term()}}
  def validate(opts, base, speeds) when is_list(opts) do
    Enum.reduce_while(opts, {:ok, base}, fn
      {key, value}, {:ok, config} when is_atom(key) ->
        case check(key, value, speeds) do
          {:ok, value} -> {:cont, {:ok, Map.put(config, key, value)}}
          :error -> {:halt, {:error, {:bad_option, key, value}}}
        end

      other, _ ->
        {:halt, {:error, {:bad_option, other, nil}}}
    end)
  end

  def validate(opts, _base, _speeds), do: {:error, {:bad_option, :options, opts}}

  defp check(:speed, v, speeds), do: if(v in speeds, do: {:ok, v}, else: :error)
  defp check(:data_bits, v, _) when v in 5..8, do: {:ok, v}
  defp check(:parity, v, _) when is_map_key(@parity, v), do: {:ok, v}
  defp check(:stop_bits, v, _) when v in [1, 2], do: {:ok, v}
  defp check(:flow_control, v, _) when is_map_key(@flow, v), do: {:ok, v}
  defp check(:active, v, _) when is_boolean(v), do: {:ok, v}
  defp check(:rx_timestamps, v, _) when is_boolean(v), do: {:ok, v}

  defp check(:rx_framing_timeout, v, _) when is_integer(v) and v >= 0,
    do: {:ok, v}

  defp check(:framing, {module, args}, _) when is_atom(module) do
    if framing?(module), do: {:ok, {module, args}}, else: :error
  end

  defp check(:framing, module, _) when is_atom(module) do
    if framing?(module), do: {:ok, {module, []}}, else: :error
  end

  defp check(_key, _value, _speeds), do: :error

  defp framing?(module) do
    Code.ensure_loaded?(module) and function_exported?(module, :init, 1) and
      function_exported?(module, :remove_framing, 2) and
      function_exported?(module, :add_framing, 2)
  end

  @doc "The line settings of `config` as the worker reads them."
  @spec encode(config()) :: binary()
  def encode(c) do
    <<c.speed::32, c.data_bits, Map.fetch!(@parity, c.parity), c.stop_bits,
      Map.fetch!(@flow, c.flow_control)>>
  end

  @doc "The worker's answer to 'G'."
  @spec decode(binary()) :: map()
  def decode(<<speed::32, data_bits, parity, stop_bits, flow>>) do
    %{
      speed: speed,
      data_bits: data_bits,
      parity: key_of(@parity, parity),
      stop_bits: stop_bits,
      flow_control: key_of(@flow, flow)
    }
  end

  defp key_of(map, value), do: Enum.find_value(map, fn {k, v} -> if v == value, do: k end)
end
