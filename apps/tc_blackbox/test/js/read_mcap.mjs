// Reads an MCAP file with @mcap/core's indexed reader (the library
// Foxglove uses) and prints what it found as one line of JSON, for the
// black box's tests to check:
//
//   node read_mcap.mjs FILE
//
// {"chunkIndexes": n, "compressions": [...], "schemas": [...],
//  "channels": {topic: {schema, encoding, count}}, "messages": n,
//  "statistics": {...}, "summaryCrc": "valid", "dataSectionCrc": "valid",
//  "first": {topic: the first message's JSON, for JSON channels}}
//
// The reader checks the summary's CRC when it opens the file and each
// chunk's CRC as it reads its messages; the data section's CRC is checked
// here. Any error prints {"error": message} and exits 1.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { crc32 } from "@foxglove/crc";
import * as zstd from "@foxglove/wasm-zstd";
import lz4 from "@foxglove/wasm-lz4";

async function main(path) {
  await zstd.isLoaded;
  await lz4.isLoaded;
  const handle = await open(path, "r");
  const { size } = await handle.stat();
  const readable = {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      await handle.read(buffer, 0, Number(length), Number(offset));
      return buffer;
    },
  };

  const reader = await McapIndexedReader.Initialize({
    readable,
    decompressHandlers: {
      zstd: (data, size) => zstd.decompress(data, Number(size)),
      lz4: (data, size) => lz4(data, Number(size)),
    },
  });

  const channels = {};
  for (const channel of reader.channelsById.values()) {
    const schema = reader.schemasById.get(channel.schemaId);
    channels[channel.topic] = {
      schema: schema ? schema.name : null,
      encoding: channel.messageEncoding,
      count: 0,
    };
  }

  const first = {};
  let messages = 0;
  let lastTime = -1n;
  let ordered = true;
  const decoder = new TextDecoder();
  for await (const message of reader.readMessages({ validateCrcs: true })) {
    const topic = reader.channelsById.get(message.channelId).topic;
    channels[topic].count += 1;
    messages += 1;
    if (message.logTime < lastTime) ordered = false;
    lastTime = message.logTime;
    // JSON channels are Foxglove's; the others (whole Erlang terms,
    // traces: "etf") are counted, not decoded, as Foxglove would
    if (!(topic in first) && channels[topic].encoding === "json")
      first[topic] = JSON.parse(decoder.decode(message.data));
  }

  // the data section's CRC: everything before the Data End record
  let dataSectionCrc = "absent";
  if (reader.dataSectionCrc !== undefined) {
    const bytes = await readable.read(0n, reader.dataEndOffset);
    dataSectionCrc = crc32(bytes) === reader.dataSectionCrc ? "valid" : "invalid";
  }

  const stats = reader.statistics;
  await handle.close();

  return {
    chunkIndexes: reader.chunkIndexes.length,
    compressions: [...new Set(reader.chunkIndexes.map((c) => c.compression))],
    profile: reader.header.profile,
    schemas: [...reader.schemasById.values()].map((s) => s.name).sort(),
    channels,
    messages,
    ordered,
    statistics: stats && {
      messageCount: Number(stats.messageCount),
      chunkCount: stats.chunkCount,
      channelCount: stats.channelCount,
      channelMessageCounts: Object.fromEntries(
        [...stats.channelMessageCounts].map(([id, n]) => [reader.channelsById.get(id).topic, Number(n)]),
      ),
    },
    summaryCrc: reader.footer.summaryCrc !== 0 ? "valid" : "absent",
    dataSectionCrc,
    first,
  };
}

main(process.argv[2]).then(
  (result) => console.log(JSON.stringify(result)),
  (error) => {
    console.log(JSON.stringify({ error: String(error && error.message ? error.message : error) }));
    process.exit(1);
  },
);
