// Read an MCAP file the way Foxglove does: @mcap/core's indexed reader (the file must have its
// summary and chunk indexes), @mcap/support's decompressors, the schema parsed by
// @foxglove/rosmsg and each message decoded by @foxglove/rosmsg2-serialization.
// Prints one JSON object: per topic, the schema, the count and the first and last message
// (numbers as numbers, bytes as their length), so a Python test can check what it decoded.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";

const path = process.argv[2];
const handle = await open(path, "r");
const size = BigInt((await handle.stat()).size);
const readable = {
  size: async () => size,
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await handle.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({
  readable,
  decompressHandlers: await loadDecompressHandlers(),
});
const readers = new Map();
const topics = {};
function plain(value) {
  if (value instanceof Uint8Array) return { bytes: value.length };
  if (typeof value === "bigint") return Number(value);
  if (Array.isArray(value) || ArrayBuffer.isView(value)) return Array.from(value, plain);
  if (value && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}
for await (const msg of reader.readMessages()) {
  const channel = reader.channelsById.get(msg.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  let decode = readers.get(channel.id);
  if (!decode) {
    const text = new TextDecoder().decode(schema.data);
    decode = new MessageReader(parse(text, { ros2: true }));
    readers.set(channel.id, decode);
  }
  const value = plain(decode.readMessage(msg.data));
  const t = (topics[channel.topic] ??= {
    schema: schema.name,
    encoding: channel.messageEncoding,
    count: 0,
  });
  if (t.count === 0) t.first = value;
  t.last = value;
  t.count += 1;
}
await handle.close();
console.log(
  JSON.stringify({
    profile: reader.header.profile,
    chunks: reader.chunkIndexes.length,
    attachments: reader.attachmentIndexes.map((a) => a.name),
    topics,
  }),
);
