defmodule ThinkingCap.Dashboard.Core.Acceptor do
  @moduledoc false
  # What the dashboard's own listeners (Core.EstopListener, the Foxglove
  # port's Foxglove.Listener) share: a listening socket for HTTP requests
  # on `host`, and an accept that waits a little, so that a listener can
  # accept between its own messages (a GenServer timeout of 0 fires when
  # its mailbox is empty).

  require Logger

  @accept_wait 200

  @doc """
  Listens on `port` (0: a free one) of `host`; `extra` options go to
  `:gen_tcp.listen/2` beside the shared ones. Returns the socket and the
  port it got, or a message naming `what` and the reason.
  """
  @spec listen(:inet.port_number(), String.t(), keyword(), String.t()) ::
          {:ok, :gen_tcp.socket(), :inet.port_number()} | {:error, String.t()}
  def listen(port, host, extra, what) do
    options =
      [
        :binary,
        packet: :http_bin,
        active: false,
        reuseaddr: true,
        backlog: 128,
        ip: ThinkingCap.Dashboard.Core.Yaws.ip(host)
      ] ++ extra

    case :gen_tcp.listen(port, options) do
      {:ok, listen} ->
        {:ok, actual} = :inet.port(listen)
        {:ok, listen, actual}

      {:error, reason} ->
        {:error, "#{what} #{port}: #{:inet.format_error(reason)}"}
    end
  end

  @doc "The port the listener registered as `name` listens on; nil when it is not running."
  @spec port(atom()) :: :inet.port_number() | nil
  def port(name) do
    case Process.whereis(name) do
      nil -> nil
      _pid -> GenServer.call(name, :port)
    end
  end

  @doc """
  Accepts a connection, waiting at most `wait` ms (#{@accept_wait} by
  default): the socket, `:none` (nobody came, or an error that was logged
  and waited out), or `:no_descriptor` (the node has no file descriptor
  left; Linux says so whether or not a connection is waiting).
  """
  @spec accept(:gen_tcp.socket(), String.t(), non_neg_integer()) ::
          {:ok, :gen_tcp.socket()} | :none | :no_descriptor
  def accept(listen, what, wait \\ @accept_wait) do
    case :gen_tcp.accept(listen, wait) do
      {:ok, socket} ->
        {:ok, socket}

      {:error, :timeout} ->
        :none

      {:error, reason} when reason in [:emfile, :enfile] ->
        :no_descriptor

      {:error, reason} ->
        Logger.warning("dashboard: #{what} accept failed: #{inspect(reason)}")
        Process.sleep(50)
        :none
    end
  end
end
