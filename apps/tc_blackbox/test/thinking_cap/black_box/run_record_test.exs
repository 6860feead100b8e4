defmodule ThinkingCap.BlackBox.RunRecordTest do
  # `bin/run --record DIR` (mix tc.run, in its own VM): the office robot,
  # simulated and driven by the whole stack, recorded into MCAP files
  # that npm's @mcap/core opens, as Foxglove would.
  use ExUnit.Case, async: true

  alias ThinkingCap.BlackBox.Test.NodeReader
  alias ThinkingCap.MCAP.Reader

  @moduletag :tmp_dir
  @moduletag timeout: 180_000

  test "a recorded run opens in @mcap/core with its chunk indexes, CRCs and Foxglove schemas",
       %{tmp_dir: dir} do
    root = Path.expand("../../../../..", __DIR__)
    recordings = Path.join(dir, "recordings")

    {output, status} =
      System.cmd(
        "mix",
        ~w(tc.run --seconds 10 --port 0 --rosbridge-port 0 --estop-port 0 --foxglove-port 0 --record) ++
          [recordings],
        cd: root,
        env: [
          {"MIX_ENV", "test"},
          {"ELIXIR_ERL_OPTIONS", "+sbwt none +sbwtdcpu none +sbwtdio none"}
        ],
        stderr_to_stdout: true
      )

    assert status == 0, output
    assert output =~ "record: #{recordings}"

    assert [file] = Path.wildcard(Path.join(recordings, "r1_*.mcap"))
    assert {:ok, node} = NodeReader.read(file)
    assert node["chunkIndexes"] >= 5
    assert node["compressions"] == ["zstd"]
    assert node["summaryCrc"] == "valid" and node["dataSectionCrc"] == "valid"
    assert node["messages"] > 1000
    assert node["statistics"]["messageCount"] == node["messages"]

    schemas = fn topic -> node["channels"][topic]["schema"] end
    assert schemas.("/r1/laser") == "foxglove.LaserScan"
    assert schemas.("/r1/map") == "foxglove.Grid"
    assert schemas.("/r1/pose") == "foxglove.PoseInFrame"
    assert schemas.("/r1/tf") == "foxglove.FrameTransform"
    assert schemas.("/r1/lps") == "thinkingcap.Tuple"

    for topic <- ~w(/r1/laser /r1/map /r1/pose /r1/odom /r1/drive /r1/plan),
        do: assert(node["channels"][topic]["count"] > 0, topic)

    # the laser as Foxglove reads it
    scan = node["first"]["/r1/laser"]
    assert scan["frame_id"] == "r1/base_link"
    assert length(scan["ranges"]) > 10
    grid = node["first"]["/r1/map"]
    assert grid["fields"] == [%{"name" => "occupancy", "offset" => 0, "type" => 2}]

    # whole rows of one byte per cell
    cells = byte_size(Base.decode64!(grid["data"]))
    assert grid["row_stride"] == grid["column_count"] and grid["cell_stride"] == 1
    assert cells > 0 and rem(cells, grid["row_stride"]) == 0

    # and as our reader reads it: the same messages
    assert {:ok, mcap} = Reader.read(file)
    assert mcap.mode == :indexed and mcap.data_crc == :valid
    assert length(mcap.messages) == node["messages"]
  end
end
