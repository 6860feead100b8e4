defmodule ThinkingCap.Robot.Create2ProtocolTest do
  use ExUnit.Case, async: true

  import Bitwise

  alias ThinkingCap.Robot.Create2.{Framing, Protocol}

  @ids [7, 19, 20, 22, 23, 25, 26, 35, 43, 44]

  describe "commands" do
    test "mode and stream opcodes" do
      assert Protocol.start() == <<128>>
      assert Protocol.reset() == <<7>>
      assert Protocol.stop() == <<173>>
      assert Protocol.safe() == <<131>>
      assert Protocol.full() == <<132>>
      assert Protocol.mode(:full) == <<132>>
      assert Protocol.sensors(7) == <<142, 7>>
      assert Protocol.query_list([7, 43]) == <<149, 2, 7, 43>>
      assert Protocol.stream([7, 19, 20]) == <<148, 3, 7, 19, 20>>
      assert Protocol.pause_stream() == <<150, 0>>
      assert Protocol.resume_stream() == <<150, 1>>
    end

    test "drive direct: right wheel first, signed big-endian, rounded and clamped to ±500" do
      assert Protocol.drive_direct(200, 200) == <<145, 0, 200, 0, 200>>
      # left -100 (0xFF9C), right 300 (0x012C)
      assert Protocol.drive_direct(-100, 300) == <<145, 0x01, 0x2C, 0xFF, 0x9C>>
      assert Protocol.drive_direct(-900.0, 700.4) == <<145, 500::16, -500::16>>
      assert Protocol.drive_direct(0.4, -0.6) == <<145, -1::16, 0::16>>
    end

    test "drive: velocity and radius, the special radii" do
      assert Protocol.drive(-200, 500) == <<137, 0xFF, 0x38, 0x01, 0xF4>>
      assert Protocol.drive(100, :straight) == <<137, 0, 100, 0x80, 0x00>>
      assert Protocol.drive(100, :spin_ccw) == <<137, 0, 100, 0, 1>>
      assert Protocol.drive(100, :spin_cw) == <<137, 0, 100, 0xFF, 0xFF>>
    end
  end

  describe "packets" do
    test "sizes" do
      assert Protocol.packet_size(7) == 1
      assert Protocol.packet_size(22) == 2
      assert Protocol.packet_size(43) == 2
      assert Protocol.packet_size(0) == nil
      assert Protocol.packet_size(200) == nil
      # 10 ids + 1 + 2 + 2 + 2 + 2 + 2 + 2 + 1 + 2 + 2
      assert Protocol.stream_length(@ids) == 28
      assert Protocol.stream_length([7, 99]) == nil
    end

    test "decoders: bumps, signed and unsigned words, the mode" do
      assert %{bump_right: true, bump_left: false, wheel_drop_right: false, wheel_drop_left: true} =
               Protocol.decode(7, <<0b1001>>)

      assert Protocol.decode(19, <<0xFF, 0xFE>>) == -2
      assert Protocol.decode(22, <<0x3E, 0x80>>) == 16_000
      assert Protocol.decode(23, <<0xFC, 0x18>>) == -1000
      assert Protocol.decode(24, <<0xFB>>) == -5
      # encoder counts are unsigned
      assert Protocol.decode(43, <<0xFF, 0xFF>>) == 65_535
      assert Protocol.decode(35, <<2>>) == :safe
      assert Protocol.decode(35, <<9>>) == :error
      assert Protocol.decode(7, <<0x10>>) == :error
      assert Protocol.decode(22, <<1>>) == :error
      assert Protocol.decode(99, <<1>>) == :error
    end

    test "encode is decode's inverse; encoder counts wrap" do
      for id <- Protocol.packet_ids(), id not in [7, 35] do
        value = if Protocol.packet_size(id) == 1, do: 100, else: 1234
        assert Protocol.decode(id, Protocol.encode(id, value)) == value
      end

      assert Protocol.decode(43, Protocol.encode(43, 70_000)) == 4464
      assert Protocol.decode(19, Protocol.encode(19, -7)) == -7
      assert Protocol.decode(35, Protocol.encode(35, :full)) == :full

      bumps = %{
        bump_right: false,
        bump_left: true,
        wheel_drop_right: true,
        wheel_drop_left: false
      }

      assert Protocol.decode(7, Protocol.encode(7, bumps)) == bumps
    end
  end

  describe "stream frames" do
    test "a frame sums to 0 and parses back" do
      frame = frame(left: 65_530, right: 12)
      assert <<19, 28, 7, _::binary>> = frame
      assert byte_size(frame) == 31
      assert Protocol.checksum_ok?(frame)

      assert {:ok, %{43 => 65_530, 44 => 12, 35 => :safe, 22 => 15_000}} =
               Protocol.parse_frame(frame, @ids)
    end

    test "a frame is refused for a wrong checksum, length, packets or header" do
      frame = frame([])
      size = byte_size(frame) - 1
      <<body::binary-size(size), sum>> = frame
      assert Protocol.parse_frame(body <> <<sum + 1 &&& 0xFF>>, @ids) == {:error, :checksum}
      assert Protocol.parse_frame(body, @ids) == {:error, :bad_length}
      assert Protocol.parse_frame(frame, [7]) == {:error, :bad_length}
      assert Protocol.parse_frame(<<0>> <> frame, @ids) == {:error, :bad_header}
      # right length and checksum, wrong ids
      other =
        Protocol.stream_frame([
          {8, 0},
          {43, 1},
          {44, 2},
          {19, 0},
          {20, 0},
          {22, 1},
          {23, 1},
          {25, 1},
          {26, 1},
          {35, :safe}
        ])

      assert Protocol.parse_frame(other, @ids) == {:error, :bad_packets}
    end

    test "query list answers: data only" do
      assert Protocol.parse_packets(<<3, 0, 10>>, [7, 43], false) ==
               {:ok, %{7 => Protocol.decode(7, <<3>>), 43 => 10}}

      assert Protocol.parse_packets(<<3, 0>>, [7, 43], false) == {:error, :bad_packets}
    end
  end

  describe "framing" do
    test "frames split anywhere come out whole" do
      frames = for i <- 1..5, do: frame(left: i * 1000, right: 65_535 - i)
      bytes = IO.iodata_to_binary(frames)

      for cut <- 1..(byte_size(bytes) - 1) do
        <<a::binary-size(cut), b::binary>> = bytes
        assert run([a, b]) == frames
      end

      # byte by byte
      assert run(for <<b <- bytes>>, do: <<b>>) == frames
    end

    test "a bad checksum, a truncated frame, garbage and a wrong n are rejected; the frames around survive" do
      good = for i <- 1..4, do: frame(left: i, right: i)
      [f1, f2, f3, f4] = good
      bad = corrupt(f2)
      <<cut::binary-size(12), _::binary>> = f3

      out = run([f1, bad, cut, f3, <<1, 2, 3>>, <<19, 5>>, f4])

      assert Enum.filter(out, &is_binary/1) == [f1, f3, f4]
      rejected = for {:rejected, reason, bytes} <- out, do: {reason, bytes}

      assert {:checksum, bad} in rejected
      assert {:truncated, cut} in rejected
      assert {:bad_length, <<19, 5>>} in rejected
      assert Enum.any?(rejected, &match?({:garbage, _}, &1))
    end

    test "a frame begun waits; the frame timeout gives it back" do
      {:ok, st} = Framing.init(@ids)
      <<part::binary-size(10), _::binary>> = frame([])
      assert {:in_frame, [], st} = Framing.remove_framing(part, st)
      assert {:ok, [^part], st} = Framing.frame_timeout(st)
      assert {:ok, [], _} = Framing.frame_timeout(st)
      f = frame([])
      assert {:ok, [^f], _} = Framing.remove_framing(f, Framing.flush(:receive, st))
    end

    test "random garbage, corrupted and cut frames between frames: never raises, every good frame comes through" do
      seed = :rand.uniform(1_000_000)
      :rand.seed(:exsss, {seed, 7, 11})

      extras =
        for _round <- 1..200 do
          pieces =
            for i <- 1..20 do
              f = frame(left: :rand.uniform(65_536) - 1, right: i)

              case :rand.uniform(6) do
                1 -> {:garbage, random_bytes(:rand.uniform(40))}
                2 -> {:corrupt, corrupt(f)}
                3 -> {:cut, binary_part(f, 0, :rand.uniform(byte_size(f) - 1))}
                _ -> {:good, f}
              end
            end

          bytes = IO.iodata_to_binary(for {_, b} <- pieces, do: b)
          out = run(chunk(bytes))

          delivered = Enum.filter(out, &is_binary/1)
          # everything delivered is a valid frame
          assert Enum.all?(delivered, &match?({:ok, _}, Protocol.parse_frame(&1, @ids))),
                 "seed #{seed}"

          # every good frame came through, in order, whatever came before it
          expected = for {:good, f} <- pieces, do: f
          assert subsequence?(expected, delivered), "seed #{seed}"

          # bad pieces (adjacent ones may merge) are rejected, not silently dropped
          if Enum.any?(pieces, fn {k, _} -> k != :good end),
            do: assert(Enum.any?(out, &match?({:rejected, _, _}, &1)), "seed #{seed}")

          length(delivered) - length(expected)
        end

      # frames made of random bytes that pass every check (an 8-bit
      # checksum: it happens) are rare
      assert Enum.sum(extras) <= 3, "seed #{seed}: #{Enum.sum(extras)} frames out of nothing"
    end

    test "pure garbage never raises" do
      :rand.seed(:exsss, {1, 2, 3})

      for _ <- 1..500 do
        bytes = random_bytes(:rand.uniform(200))
        {:ok, st} = Framing.init(@ids)
        {status, frames, st} = Framing.remove_framing(bytes, st)
        assert status in [:ok, :in_frame]
        assert is_list(frames)
        {:ok, _, _} = Framing.frame_timeout(st)
      end

      # garbage made of headers and the expected n
      {:ok, st} = Framing.init(@ids)
      {_, frames, _} = Framing.remove_framing(:binary.copy(<<19, 28, 7>>, 40), st)
      assert Enum.all?(frames, &match?({:rejected, _, _}, &1))
    end
  end

  defp frame(opts) do
    Protocol.stream_frame([
      {7, %{bump_left: Keyword.get(opts, :bump, false)}},
      {19, 5},
      {20, -1},
      {22, 15_000},
      {23, -300},
      {25, 2500},
      {26, 3000},
      {35, :safe},
      {43, Keyword.get(opts, :left, 0)},
      {44, Keyword.get(opts, :right, 0)}
    ])
  end

  defp corrupt(frame) do
    size = byte_size(frame) - 1
    <<body::binary-size(size), sum>> = frame
    body <> <<sum + 1 &&& 0xFF>>
  end

  defp subsequence?([], _), do: true
  defp subsequence?(_, []), do: false
  defp subsequence?([x | xs], [x | ys]), do: subsequence?(xs, ys)
  defp subsequence?(xs, [_ | ys]), do: subsequence?(xs, ys)

  defp random_bytes(n), do: for(_ <- 1..n, into: <<>>, do: <<:rand.uniform(256) - 1>>)

  defp chunk(<<>>), do: []

  defp chunk(bytes) do
    n = min(byte_size(bytes), :rand.uniform(50))
    <<c::binary-size(n), rest::binary>> = bytes
    [c | chunk(rest)]
  end

  # the framing over the chunks, then, as the driver does, a partial that
  # is a whole frame is one
  defp run(chunks) do
    {:ok, st} = Framing.init(@ids)

    {out, st} =
      Enum.flat_map_reduce(chunks, st, fn c, st ->
        {_, fs, st} = Framing.remove_framing(c, st)
        {fs, st}
      end)

    {:ok, partial, _} = Framing.frame_timeout(st)
    out ++ Enum.map(partial, &partial_frame/1)
  end

  defp partial_frame(bytes) do
    case Protocol.parse_frame(bytes, @ids) do
      {:ok, _} -> bytes
      {:error, _} -> {:rejected, :partial, bytes}
    end
  end
end
