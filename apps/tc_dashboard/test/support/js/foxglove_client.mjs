// A Foxglove WebSocket client for tests, on Foxglove's own npm
// `@foxglove/ws-protocol` (FoxgloveClient) over npm `ws`, as Foxglove's
// examples use it (the dashboard's assets/node_modules). It prints one
// JSON object a line on stdout, each with an "event" field, and exits 0
// when its script is done.
//
//   node foxglove_client.mjs URL SUBPROTOCOL ROBOT
//
// It connects with SUBPROTOCOL, reports serverInfo and the channels
// advertised, subscribes ROBOT's laser, map and pose channels, and
// reports the first message of each, decoded (JSON.parse of the payload).
// A refused connection prints "refused" with the HTTP status.

import { createRequire } from "node:module";

const require = createRequire(new URL("../../../assets/package.json", import.meta.url));
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");

const [url, subprotocol, robot] = process.argv.slice(2);
const print = (event, data = {}) => console.log(JSON.stringify({ event, ...data }));

setTimeout(() => {
  print("timeout");
  process.exit(2);
}, 20000);

const ws = new WebSocket(url, [subprotocol]);
ws.on("unexpected-response", (_request, response) => {
  print("refused", { status: response.statusCode });
  process.exit(0);
});
ws.on("open", () => print("open", { protocol: ws.protocol }));

const client = new FoxgloveClient({ ws });
const wanted = new Map([
  [`/${robot}/laser`, "scan"],
  [`/${robot}/map`, "map"],
  [`/${robot}/pose`, "pose"],
]);
const bySubscription = new Map();
const seen = new Set();
const decoder = new TextDecoder();

client.on("error", (e) => print("error", { message: String(e?.message ?? e) }));
client.on("serverInfo", (info) => print("serverInfo", info));
client.on("status", (status) => print("status", status));
client.on("advertise", (channels) => {
  print("advertise", {
    channels: channels.map(({ id, topic, encoding, schemaName, schemaEncoding, schema }) => ({
      id,
      topic,
      encoding,
      schemaName,
      schemaEncoding,
      schemaTitle: JSON.parse(schema).title,
    })),
  });
  for (const channel of channels) {
    const name = wanted.get(channel.topic);
    if (name) bySubscription.set(client.subscribe(channel.id), { name, channel });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const { name, channel } = bySubscription.get(subscriptionId) ?? {};
  if (!name || seen.has(name)) return;
  seen.add(name);
  const message = JSON.parse(decoder.decode(data));
  print(name, {
    topic: channel.topic,
    schemaName: channel.schemaName,
    timestamp: Number(timestamp),
    message: name === "map" ? { ...message, data: message.data.length } : message,
  });
  if (seen.size === wanted.size) {
    client.close();
    print("done");
    process.exit(0);
  }
});
client.on("close", () => {
  print("closed");
  process.exit(0);
});
