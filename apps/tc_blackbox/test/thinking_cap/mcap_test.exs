defmodule ThinkingCap.MCAPTest do
  use ExUnit.Case, async: true

  alias ThinkingCap.MCAP
  alias ThinkingCap.MCAP.{Compression, Message, Reader, Writer}

  @algorithms ["", "zstd", "lz4"]

  # two schemas, three channels (one without a schema), messages
  # interleaved with times out of order, enough to fill several chunks
  defp sample(opts, count \\ 600) do
    {:ok, w} = Writer.new(opts)
    {:ok, s1, w} = Writer.add_schema(w, "foxglove.LaserScan", "jsonschema", ~s({"type":"object"}))
    {:ok, s2, w} = Writer.add_schema(w, "thinkingcap.Tuple", "jsonschema", "{}")
    {:ok, c0, w} = Writer.add_channel(w, s1, "/r1/laser", "json", %{"robot" => "r1"})
    {:ok, c1, w} = Writer.add_channel(w, s2, "/r1/drive", "json")
    {:ok, c2, w} = Writer.add_channel(w, 0, "/r1/raw", "application/octet-stream")

    {w, sent} =
      Enum.reduce(1..count, {w, []}, fn i, {w, sent} ->
        channel = Enum.at([c0, c1, c2], rem(i, 3))
        # a little out of order: every tenth message is stamped earlier
        log_time = 1_000_000_000 + i * 1_000 - if(rem(i, 10) == 0, do: 5_500, else: 0)
        data = :binary.copy(<<i::16>>, rem(i, 50) + 1)
        {:ok, w} = Writer.add_message(w, channel, log_time, log_time - 7, [data], i)
        {w, [{channel, log_time, data, i} | sent]}
      end)

    {:ok, bin} = Writer.close(w)
    {bin, Enum.reverse(sent)}
  end

  describe "write, then read back" do
    for algorithm <- @algorithms do
      test "every record kind, compression #{inspect(algorithm)}" do
        {bin, sent} = sample(compression: unquote(algorithm), chunk_bytes: 4_000)

        assert binary_part(bin, 0, 8) == MCAP.magic()
        assert binary_part(bin, byte_size(bin) - 8, 8) == MCAP.magic()

        assert {:ok, file} = Reader.read_binary(bin)
        assert file.mode == :indexed
        assert file.header == %{profile: "", library: "thinkingcap"}
        assert file.data_crc == :valid
        assert file.summary_crc == :valid
        refute file.truncated

        assert Enum.map(file.schemas, fn {id, s} -> {id, s.name, s.encoding} end) |> Enum.sort() ==
                 [{1, "foxglove.LaserScan", "jsonschema"}, {2, "thinkingcap.Tuple", "jsonschema"}]

        assert file.channels[0].topic == "/r1/laser"
        assert file.channels[0].metadata == %{"robot" => "r1"}
        assert file.channels[2].schema_id == 0

        # several chunks, each indexed, each in the compression asked for
        assert length(file.chunk_indexes) > 3
        assert file.chunks == length(file.chunk_indexes)
        assert Enum.all?(file.chunk_indexes, &(&1.compression == unquote(algorithm)))
        assert Enum.all?(file.chunk_indexes, &(map_size(&1.message_index_offsets) == 3))

        stats = file.statistics
        assert stats.message_count == 600
        assert stats.schema_count == 2 and stats.channel_count == 3
        assert stats.chunk_count == length(file.chunk_indexes)
        assert stats.channel_message_counts == %{0 => 200, 1 => 200, 2 => 200}
        times = Enum.map(sent, &elem(&1, 1))
        assert stats.message_start_time == Enum.min(times)
        assert stats.message_end_time == Enum.max(times)

        # indexed: every message, in log time order
        got =
          for %Message{} = m <- file.messages, do: {m.channel_id, m.log_time, m.data, m.sequence}

        assert got == Enum.sort_by(sent, &elem(&1, 1))
        assert Enum.all?(file.messages, &(&1.publish_time == &1.log_time - 7))

        # linear, without the summary: the same messages in file order
        linear = strip_summary(bin)
        assert {:ok, lfile} = Reader.read_binary(linear)
        assert lfile.mode == :linear and lfile.data_crc == :valid and not lfile.truncated

        assert Enum.map(lfile.messages, &{&1.channel_id, &1.log_time, &1.data, &1.sequence}) ==
                 sent
      end
    end

    test "a chunk stream compresses what it is given, piece by piece, chunk after chunk" do
      for algorithm <- @algorithms do
        stream = Compression.stream(algorithm)

        for round <- 1..3 do
          # small pieces (a normal scheduler), one big (a dirty one), iodata
          pieces =
            for i <- 1..40,
                do: [:binary.copy(<<round, i>>, i * 50), "json", [?{, "#{i}", ?}]]

          big = :crypto.strong_rand_bytes(70_000) <> :binary.copy("x", 200_000)
          pieces = pieces ++ [big]

          for piece <- pieces,
              do: :ok = Compression.add(stream, piece, IO.iodata_length(piece))

          data = IO.iodata_to_binary(pieces)
          %{compressed: compressed, crc: crc, size: size} = Compression.finish(stream)
          assert size == byte_size(data) and crc == :erlang.crc32(data)
          assert {:ok, ^data} = Compression.decompress(algorithm, compressed, size)
        end

        # a chunk with nothing in it
        %{compressed: compressed, crc: crc, size: 0} = Compression.finish(stream)
        assert crc == 0 and {:ok, ""} == Compression.decompress(algorithm, compressed, 0)
      end
    end

    test "a chunk stream makes message records, their sequences and message indexes" do
      for algorithm <- @algorithms do
        stream = Compression.stream(algorithm)
        head = "a schema record, as given"
        :ok = Compression.add(stream, head, byte_size(head))
        t = 1_800_000_000_000_000_000
        # channel, sequence, log time, publish time, data (log times out of order)
        sent = [
          {3, :next, t + 20, 5, "json"},
          {1, :next, t + 10, 6, ["{", "iodata", ?}]},
          {3, 77, t + 5, 7, "etf"},
          {3, :next, t + 30, 8, :binary.copy("x", 70_000)}
        ]

        sizes = for {c, s, l, p, d} <- sent, do: Compression.message(stream, c, s, l, p, d)
        assert Compression.size(stream) == {List.last(sizes), 4}

        chunk = Compression.finish(stream)
        {:ok, records} = Compression.decompress(algorithm, chunk.compressed, chunk.size)
        assert chunk.crc == :erlang.crc32(records) and byte_size(records) == List.last(sizes)
        assert {chunk.start_time, chunk.end_time} == {t + 5, t + 30}

        # the records: the head, then each message with its offset
        <<^head::binary-size(byte_size(head)), rest::binary>> = records
        {messages, ""} = read_messages(rest, byte_size(head), [])

        assert Enum.map(messages, fn {_at, m} -> m end) == [
                 {3, 1, t + 20, 5, "json"},
                 {1, 1, t + 10, 6, "{iodata}"},
                 {3, 77, t + 5, 7, "etf"},
                 {3, 2, t + 30, 8, :binary.copy("x", 70_000)}
               ]

        [at1, at2, at3, at4] = Enum.map(messages, &elem(&1, 0))

        # one Message Index a channel, by channel, entries by log time
        index3 =
          <<3::little-16, 48::little-32, t + 5::little-64, at3::little-64, t + 20::little-64,
            at1::little-64, t + 30::little-64, at4::little-64>>

        index1 = <<1::little-16, 16::little-32, t + 10::little-64, at2::little-64>>

        assert chunk.indexes ==
                 <<7, byte_size(index1)::little-64, index1::binary, 7,
                   byte_size(index3)::little-64, index3::binary>>

        assert chunk.channels == [{1, 1, 0}, {3, 3, 9 + byte_size(index1)}]

        # the next chunk: sequences go on, the rest starts again
        Compression.message(stream, 1, :next, t, t, "")
        assert %{size: 31, channels: [{1, 1, 0}]} = Compression.finish(stream)
        Compression.message(stream, 1, :next, t, t, "again")
        chunk = Compression.finish(stream)
        {:ok, records} = Compression.decompress(algorithm, chunk.compressed, chunk.size)
        assert {[{0, {1, 3, ^t, ^t, "again"}}], ""} = read_messages(records, 0, [])
      end
    end

    test "messages given in lists make the file they make one at a time" do
      for algorithm <- @algorithms do
        opts = [compression: algorithm, chunk_bytes: 4_096]
        {:ok, a} = Writer.new(opts)
        {:ok, b} = Writer.new(opts)
        {:ok, ca, a} = Writer.add_channel(a, 0, "/r1/raw", "etf")
        {:ok, cb, b} = Writer.add_channel(b, 0, "/r1/raw", "etf")
        assert ca == cb

        # lists of 1 to 40 messages, some larger than a chunk, so that
        # chunks close inside a list; sequences given and :next
        messages =
          for i <- 1..900 do
            data = if rem(i, 97) == 0, do: :binary.copy("y", 5_000), else: [<<i::32>>, "x"]
            {ca, if(rem(i, 7) == 0, do: i, else: :next), 1_000 + i, 2_000 + i, data}
          end

        a =
          Enum.reduce(messages, a, fn {c, s, l, p, d}, w ->
            {:ok, w} = Writer.add_message(w, c, l, p, d, s)
            w
          end)

        b =
          messages
          |> Enum.chunk_every(40)
          |> Enum.with_index()
          |> Enum.reduce(b, fn {list, k}, w ->
            {:ok, w} = Writer.add_messages(w, Enum.take(list, rem(k, 40) + 1), 0)
            {:ok, w} = Writer.add_messages(w, Enum.drop(list, rem(k, 40) + 1), 0)
            w
          end)

        {:ok, bin_a} = Writer.close(a)
        {:ok, bin_b} = Writer.close(b)
        assert bin_b == bin_a
        {:ok, file} = Reader.read_binary(bin_b)
        assert length(file.messages) == 900 and length(file.chunk_indexes) >= 10
      end
    end

    test "an empty file has a header, a summary and a footer" do
      {:ok, w} = Writer.new()
      {:ok, bin} = Writer.close(w)
      assert {:ok, file} = Reader.read_binary(bin)
      assert file.messages == [] and file.statistics.message_count == 0
    end

    test "a file on disk" do
      path = Path.join(System.tmp_dir!(), "mcap_test_#{System.unique_integer([:positive])}.mcap")
      on_exit(fn -> File.rm(path) end)
      {:ok, w} = Writer.open(path, compression: "lz4")
      {:ok, s, w} = Writer.add_schema(w, "s", "jsonschema", "{}")
      {:ok, c, w} = Writer.add_channel(w, s, "/t", "json")
      {:ok, w} = Writer.add_message(w, c, 5, 5, ~s({"a":1}))
      {:ok, size} = Writer.close(w)
      assert File.stat!(path).size == size
      assert {:ok, %{messages: [%Message{data: ~s({"a":1})}]}} = Reader.read(path)
    end

    test "bad options are refused" do
      assert {:error, {:compression, "bzip2"}} = Writer.new(compression: "bzip2")
      assert {:error, {:chunk_bytes, 0}} = Writer.new(chunk_bytes: 0)
    end
  end

  # the data section, then a bare footer: no summary
  defp strip_summary(bin) do
    {:ok, %{summary_start: start}} = footer(bin)
    data = binary_part(bin, 0, start)
    footer = <<0x02, 20::little-64, 0::little-64, 0::little-64, 0::little-32>>
    data <> footer <> MCAP.magic()
  end

  defp footer(bin) do
    size = byte_size(bin)
    <<_::binary-size(size - 37), 0x02, 20::little-64, s::little-64, _::binary>> = bin
    {:ok, %{summary_start: s}}
  end

  describe "a file cut short" do
    test "is read up to its last whole chunk" do
      {bin, sent} = sample(compression: "zstd", chunk_bytes: 4_000)
      {:ok, %{chunk_indexes: indexes}} = Reader.read_binary(bin)
      # cut in the middle of the fourth chunk
      fourth = Enum.at(indexes, 3)
      cut = binary_part(bin, 0, fourth.chunk_start_offset + div(fourth.chunk_length, 2))

      assert {:ok, file} = Reader.read_binary(cut)
      assert file.mode == :linear and file.truncated
      assert file.chunks == 3
      # the messages of the first three chunks
      expected = Enum.take(indexes, 3) |> Enum.map(&map_size(&1.message_index_offsets))
      assert Enum.all?(expected, &(&1 == 3))
      n = length(file.messages)
      assert n > 0 and n < 600

      assert Enum.map(file.messages, &{&1.channel_id, &1.log_time, &1.data, &1.sequence}) ==
               Enum.take(sent, n)
    end

    test "just after a chunk, it has every message of the chunks before" do
      {bin, sent} = sample(compression: "", chunk_bytes: 4_000)
      {:ok, %{chunk_indexes: [first, second | _]}} = Reader.read_binary(bin)
      cut = binary_part(bin, 0, second.chunk_start_offset)
      assert {:ok, file} = Reader.read_binary(cut)
      assert file.truncated and file.chunks == 1

      # the first chunk's messages, as its message indexes count them
      in_first =
        Enum.sum(
          for {_channel, offset} <- first.message_index_offsets do
            {:ok, 0x07, content, _} = ThinkingCap.MCAP.Core.Decode.next(bin, offset)
            {:ok, {_, entries}} = ThinkingCap.MCAP.Core.Decode.message_index(content)
            length(entries)
          end
        )

      assert in_first > 0

      assert Enum.map(file.messages, &{&1.channel_id, &1.log_time, &1.data, &1.sequence}) ==
               Enum.take(sent, in_first)
    end
  end

  describe "bad input" do
    test "is refused with a reason" do
      {bin, _} = sample(compression: "zstd", chunk_bytes: 4_000)
      assert Reader.read_binary("") == {:error, :bad_magic}
      assert Reader.read_binary("not an mcap file at all") == {:error, :bad_magic}
      assert {:error, {:bad_record, :header, 8}} = Reader.read_binary(MCAP.magic())

      # a flipped byte inside the first chunk's compressed records
      {:ok, %{chunk_indexes: [first | _]}} = Reader.read_binary(bin)
      at = first.chunk_start_offset + first.chunk_length - 10
      assert {:error, reason} = Reader.read_binary(flip(bin, at))
      assert match?({:crc, _, _}, reason) or match?({:decompress, _, _}, reason)

      # a flipped byte in the summary
      {:ok, %{summary_start: s}} = footer(bin)
      assert {:error, {:crc, :summary, ^s}} = Reader.read_binary(flip(bin, s + 20))
    end

    test "a chunk bigger than allowed is refused" do
      {bin, _} = sample(compression: "zstd", chunk_bytes: 4_000)
      assert {:error, {:too_big, :chunk}} = Reader.read_binary(bin, max_chunk_bytes: 100)
      assert {:error, {:too_big, :total}} = Reader.read_binary(bin, max_total_bytes: 10_000)
    end

    # 3,000 reads: the limits keep a length made huge from allocating much
    @tag timeout: 300_000
    test "thousands of random mutations: an answer each time, never an exception" do
      for algorithm <- @algorithms do
        # a small file of a few chunks: every mutation lands near something
        {bin, _} = sample([compression: algorithm, chunk_bytes: 1_000], 90)
        linear = strip_summary(bin)
        :rand.seed(:exsss, {1, 2, 3})

        for _ <- 1..500, source <- [bin, linear] do
          mutated = mutate(source)
          result = Reader.read_binary(mutated, max_chunk_bytes: 100_000, max_total_bytes: 300_000)
          assert match?({:ok, %Reader{}}, result) or match?({:error, _}, result)
        end
      end
    end
  end

  defp flip(bin, at) do
    <<head::binary-size(at), byte, rest::binary>> = bin
    <<head::binary, Bitwise.bxor(byte, 0xFF), rest::binary>>
  end

  # a random byte changed, a stretch cut out, the file cut short, random
  # bytes put in, or a length field made huge
  defp mutate(bin) do
    size = byte_size(bin)
    at = :rand.uniform(size) - 1

    case :rand.uniform(5) do
      1 ->
        <<head::binary-size(at), _, rest::binary>> = bin
        <<head::binary, :rand.uniform(256) - 1, rest::binary>>

      2 ->
        n = min(:rand.uniform(64), size - at)
        binary_part(bin, 0, at) <> binary_part(bin, at + n, size - at - n)

      3 ->
        binary_part(bin, 0, at)

      4 ->
        binary_part(bin, 0, at) <>
          :crypto.strong_rand_bytes(:rand.uniform(32)) <>
          binary_part(bin, at, size - at)

      5 ->
        n = min(8, size - at)

        binary_part(bin, 0, at) <>
          :binary.copy(<<0xFF>>, n) <> binary_part(bin, at + n, size - at - n)
    end
  end

  # Message records: [{offset, {channel, sequence, log_time, publish_time, data}}]
  defp read_messages(<<5, len::little-64, body::binary-size(len), rest::binary>>, at, acc) do
    <<channel::little-16, sequence::little-32, log::little-64, publish::little-64, data::binary>> =
      body

    read_messages(rest, at + 9 + len, [{at, {channel, sequence, log, publish, data}} | acc])
  end

  defp read_messages(rest, _at, acc), do: {Enum.reverse(acc), rest}
end
