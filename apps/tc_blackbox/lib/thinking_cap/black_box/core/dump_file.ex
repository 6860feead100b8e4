defmodule ThinkingCap.BlackBox.Core.DumpFile do
  @moduledoc false
  # Writes a ring buffer's entries into one MCAP file, with the
  # recorder's conversion (BlackBox.Foxglove) and times: the log time is
  # the receipt, the publish time the tuple's stamp when it has one.
  alias ThinkingCap.BlackBox.Foxglove
  alias ThinkingCap.MCAP.Writer

  @spec write(Path.t(), atom(), [{integer(), tuple(), non_neg_integer()}], String.t()) ::
          {:ok, non_neg_integer()} | {:error, term()}
  def write(path, robot, entries, compression) do
    with :ok <- File.mkdir_p(Path.dirname(path)),
         {:ok, w} <- Writer.open(path, compression: compression) do
      acc = %{w: w, robot: robot, channels: %{}, schemas: %{}, sequence: %{}, n: 0}

      try do
        acc = Enum.reduce(entries, acc, &entry/2)
        {:ok, _} = Writer.close(acc.w)
        {:ok, acc.n}
      rescue
        e in MatchError ->
          Writer.abandon(acc.w)
          {:error, e.term}
      end
    end
  end

  defp entry({time, tuple, _size}, acc) do
    publish = Foxglove.stamp_ns(tuple) || time

    Enum.reduce(Foxglove.messages(tuple, time), acc, fn {topic, schema, json}, acc ->
      {channel, acc} = channel(acc, topic, schema)
      sequence = Map.get(acc.sequence, channel, 0) + 1
      {:ok, w} = Writer.add_message(acc.w, channel, time, publish, json, sequence)
      %{acc | w: w, sequence: Map.put(acc.sequence, channel, sequence), n: acc.n + 1}
    end)
  end

  defp channel(acc, topic, schema) do
    case acc.channels do
      %{^topic => id} ->
        {id, acc}

      _ ->
        {schema_id, acc} = schema(acc, schema)
        metadata = %{"robot" => Atom.to_string(acc.robot)}
        {:ok, id, w} = Writer.add_channel(acc.w, schema_id, topic, "json", metadata)
        {id, %{acc | w: w, channels: Map.put(acc.channels, topic, id)}}
    end
  end

  defp schema(acc, name) do
    case acc.schemas do
      %{^name => id} ->
        {id, acc}

      _ ->
        {:ok, id, w} = Writer.add_schema(acc.w, name, "jsonschema", Foxglove.schema(name))
        {id, %{acc | w: w, schemas: Map.put(acc.schemas, name, id)}}
    end
  end
end
