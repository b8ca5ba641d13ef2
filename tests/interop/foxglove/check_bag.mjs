// Decode every message of a ttball bag with Foxglove's own parsers (the ones the Foxglove app
// uses) and compare every field with what ttball says it wrote.
//
// Usage: node check_bag.mjs BAG.mcap DUMP.jsonl
//
// DUMP.jsonl is `ttball dump BAG.mcap` (one JSON object per message, in log-time order).
// - @mcap/core's indexed reader (chunk indexes, log-time order, CRCs validated) with
//   @mcap/support's decompressors reads the messages; @foxglove/rosmsg parses each channel's
//   ros2msg schema and @foxglove/rosmsg2-serialization decodes the CDR payloads. Every field
//   must equal ttball's (float32 after rounding both sides to float32), and every payload must be
//   consumed exactly (no trailing bytes: the schema is the payload's).
// - @mcap/core's stream reader reads the whole file record by record, validating every CRC, and
//   must see as many messages.
// - Each standard type's definition in the bag (std_msgs, geometry_msgs, ...) is compared with
//   @foxglove/rosmsg-msgs-common's ROS 2 Humble and Jazzy copies: same fields, same constants
//   (a constant only one distribution has is reported as such).
// Prints what it checked; exit code 0 when everything matches, 1 otherwise.

import { readFile } from "node:fs/promises";
import { plain } from "./plain.mjs";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import { ros2humble, ros2jazzy } from "@foxglove/rosmsg-msgs-common";

const [bagPath, dumpPath] = process.argv.slice(2);
const bytes = new Uint8Array(await readFile(bagPath));
const expected = (await readFile(dumpPath, "utf8"))
  .split("\n")
  .filter((line) => line.trim())
  // log_time is a u64 beyond a double's 53 bits: taken from the text.
  .map((line) => ({ ...JSON.parse(line), log_time: BigInt(/"log_time":(\d+)/.exec(line)[1]) }));
const decompressHandlers = await loadDecompressHandlers();
const problems = [];


function compare(ours, theirs, path) {
  if (problems.length > 20) return;
  if (Array.isArray(ours)) {
    if (!Array.isArray(theirs) || ours.length !== theirs.length) {
      problems.push(`${path}: ${ours.length} elements vs ${JSON.stringify(theirs)?.slice(0, 80)}`);
      return;
    }
    ours.forEach((v, i) => compare(v, theirs[i], `${path}[${i}]`));
  } else if (ours && typeof ours === "object") {
    const a = Object.keys(ours).sort();
    const b = theirs && typeof theirs === "object" ? Object.keys(theirs).sort() : [];
    if (a.join() !== b.join()) {
      problems.push(`${path}: fields ${a} vs ${b}`);
      return;
    }
    for (const key of a) compare(ours[key], theirs[key], `${path}.${key}`);
  } else if (typeof ours === "number") {
    if (!(ours === theirs || Math.fround(ours) === Math.fround(theirs))) {
      problems.push(`${path}: ${ours} vs ${theirs}`);
    }
  } else if (ours !== theirs) {
    problems.push(`${path}: ${JSON.stringify(ours)} vs ${JSON.stringify(theirs)}`);
  }
}

// The indexed reader, in log-time order.
const readable = {
  size: async () => BigInt(bytes.byteLength),
  read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const decoders = new Map();
const definitions = new Map();
for (const [id, channel] of reader.channelsById) {
  const schema = reader.schemasById.get(channel.schemaId);
  if (!schema || schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
    problems.push(`${channel.topic}: schema ${schema?.encoding} / ${channel.messageEncoding}`);
    continue;
  }
  const parsed = parse(new TextDecoder().decode(schema.data), { ros2: true });
  decoders.set(id, { reader: new MessageReader(parsed), type: schema.name, topic: channel.topic });
  for (const definition of parsed.slice(1)) definitions.set(definition.name, definition);
}
const known = new Set(expected.map((e) => e.type));
const counts = {};
let index = 0;
for await (const message of reader.readMessages({ validateCrcs: true })) {
  const decoder = decoders.get(message.channelId);
  if (!decoder || !known.has(decoder.type)) continue;
  const ours = expected[index++];
  const where = `${decoder.topic}@${message.logTime}`;
  if (!ours || ours.topic !== decoder.topic || ours.log_time !== message.logTime) {
    problems.push(`order: ${where} vs ${ours?.topic}@${ours?.log_time}`);
    break;
  }
  const decoded = decoder.reader.readMessage(message.data);
  if (decoder.reader.lastReadHadTrailingBytes()) problems.push(`${where}: trailing bytes`);
  compare(ours.message, plain(decoded), where);
  counts[decoder.topic] = (counts[decoder.topic] ?? 0) + 1;
}
if (index !== expected.length) problems.push(`${index} messages decoded, ttball wrote ${expected.length}`);

// The stream reader, every record, every CRC.
const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(bytes);
let streamed = 0;
let records = 0;
for (let record; (record = stream.nextRecord()); ) {
  records++;
  if (record.type === "Message") streamed++;
}
if (!stream.done()) problems.push("the stream reader did not reach the end of the file");
const indexedTotal = Object.values(counts).reduce((a, b) => a + b, 0);
if (streamed < indexedTotal) problems.push(`stream reader: ${streamed} messages, indexed: ${indexedTotal}`);

// The standard definitions against Foxglove's copies of ROS 2 Humble and Jazzy.
const field = (f) =>
  JSON.stringify([f.name, f.type, f.isArray ?? false, f.arrayLength ?? null, f.isComplex ?? false, f.upperBound ?? null, f.arrayUpperBound ?? null]);
const constant = (f) => `${f.name}=${f.value}`;
const distributions = { humble: ros2humble, jazzy: ros2jazzy };
const standard = [];
for (const [name, ours] of [...definitions].sort()) {
  if (name.startsWith("ttball_msgs/")) continue;
  const key = name.replace("/msg/", "/");
  for (const [distribution, copies] of Object.entries(distributions)) {
    const theirs = copies[key];
    if (!theirs) {
      problems.push(`${name}: not in ${distribution}`);
      continue;
    }
    const a = ours.definitions.filter((f) => !f.isConstant).map(field);
    const b = theirs.definitions.filter((f) => !f.isConstant).map(field);
    if (a.join() !== b.join()) problems.push(`${name} (${distribution}): fields ${a} vs ${b}`);
    const ca = ours.definitions.filter((f) => f.isConstant).map(constant);
    const cb = theirs.definitions.filter((f) => f.isConstant).map(constant);
    const missing = cb.filter((c) => !ca.includes(c));
    const extra = ca.filter((c) => !cb.includes(c));
    if (extra.length) problems.push(`${name} (${distribution}): constants not in ${distribution}: ${extra}`);
    standard.push(`${name} (${distribution}${missing.length ? `; ${distribution} adds ${missing}` : ""})`);
  }
}

for (const p of problems.slice(0, 20)) console.log("MISMATCH", p);
console.log("checked", Object.entries(counts).sort().map(([t, n]) => `${t}: ${n}`).join(", "));
console.log(`stream reader: ${records} records, ${streamed} messages, CRCs valid`);
console.log("standard definitions", standard.join(", "));
process.exit(problems.length ? 1 : 0);
