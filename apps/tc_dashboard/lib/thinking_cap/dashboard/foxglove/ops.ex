defmodule ThinkingCap.Dashboard.Foxglove.Ops do
  @moduledoc false
  # The operations a Foxglove client sends: `subscribe` and `unsubscribe`.
  # Everything else (the capabilities the endpoint does not announce:
  # publishing, parameters, services, the connection graph, assets) gets a
  # status error and changes nothing; so does a malformed message. Each
  # subscription is checked on its own: the good ones of a message are
  # taken even when another is refused.

  alias ThinkingCap.Dashboard.Foxglove.{Messages, Streams}

  @max_subscriptions 256
  @uint32 0..0xFFFF_FFFF

  @doc "A client's text frame: `{frames, state}`."
  @spec handle_text(binary(), map()) :: {[Messages.frame()], map()}
  def handle_text(text, state) do
    case decode(text) do
      {:ok, %{"op" => "subscribe", "subscriptions" => subs}} when is_list(subs) ->
        subscribe(subs, state)

      {:ok, %{"op" => "unsubscribe", "subscriptionIds" => ids}} when is_list(ids) ->
        unsubscribe(ids, state)

      {:ok, %{"op" => op}} when op in ["subscribe", "unsubscribe"] ->
        {[error("#{op}: malformed (see the protocol's spec)")], state}

      {:ok, %{"op" => op}} when is_binary(op) ->
        {[error("#{String.slice(op, 0, 64)}: not supported by this server")], state}

      {:ok, _other} ->
        {[error("a JSON object with an \"op\" is expected")], state}

      :error ->
        {[error("not JSON")], state}
    end
  end

  defp decode(text) do
    {:ok, :jiffy.decode(text, [:return_maps])}
  catch
    _kind, _reason -> :error
  end

  defp subscribe(subs, state) do
    {frames, state} =
      Enum.reduce(subs, {[], state}, fn sub, {frames, state} ->
        case check_subscribe(sub, state) do
          {:ok, sub_id, channel} ->
            state = %{state | subs: Map.put(state.subs, sub_id, channel.id)}
            {latest, state} = Streams.latest(Streams.sync_tags(state), sub_id, channel)
            {frames ++ latest, state}

          {:error, message} ->
            {frames ++ [error(message)], state}
        end
      end)

    {frames, state}
  end

  defp check_subscribe(%{"id" => sub, "channelId" => channel}, state)
       when sub in @uint32 and is_integer(channel) do
    cond do
      Map.has_key?(state.subs, sub) ->
        {:error, "subscribe: subscription id #{sub} is in use"}

      not Map.has_key?(state.channels, channel) ->
        {:error, "subscribe: no channel #{channel}"}

      map_size(state.subs) >= @max_subscriptions ->
        {:error, "subscribe: #{@max_subscriptions} subscriptions at most"}

      true ->
        {:ok, sub, state.channels[channel]}
    end
  end

  defp check_subscribe(_sub, _state),
    do: {:error, "subscribe: each subscription needs an integer id (uint32) and channelId"}

  defp unsubscribe(ids, state) do
    {known, unknown} = Enum.split_with(ids, &Map.has_key?(state.subs, &1))
    state = Streams.sync_tags(%{state | subs: Map.drop(state.subs, known)})

    frames =
      for id <- unknown,
          do: error("unsubscribe: no subscription #{inspect(id) |> String.slice(0, 64)}")

    {frames, state}
  end

  defp error(message), do: Messages.status(:error, message)
end
