// Writes the MCAP conformance corpus's files from their JSON specifications with Foxglove's own
// writer (@mcap/core's McapWriter), one file per specification, in the layout its variant names.
//
// Usage: node write_conformance.mjs CORPUS_DIR OUT_DIR
//
// The corpus (tests/data/mcap_conformance/, from foxglove/mcap) holds each variant's JSON: the
// records a reader must return, and `meta.variant.features`. Its .mcap files are Git LFS objects
// that the copy does not hold, so they are written here: schemas, channels, messages,
// attachments and metadata in the JSON's order; the features as McapWriter's options (ch chunks,
// mx message indexes, chx chunk indexes, st statistics, sum summary offsets, rsh / rch schemas /
// channels repeated in the summary, ax attachment index, mdx metadata index). `pad` (extra
// trailing bytes in every record that may have them, as a newer writer's fields would be) is not
// something McapWriter can write: those variants are laid out record by record with
// @mcap/core's McapRecordBuilder and its `padRecords` option, the way the corpus's own generator
// lays them out (`writePadded`), and read back with @mcap/core's stream reader. Prints one line
// per file written (OUT_DIR/VARIANT.mcap) and the count of padded ones among them.

import { mkdir, readdir, readFile, writeFile } from "node:fs/promises";
import { join } from "node:path";
import { McapConstants, McapRecordBuilder, McapStreamReader, McapWriter } from "@mcap/core";

const [corpus, out] = process.argv.slice(2);
await mkdir(out, { recursive: true });

const OPTIONS = {
  ch: "useChunks",
  mx: "useMessageIndex",
  chx: "useChunkIndex",
  st: "useStatistics",
  sum: "useSummaryOffsets",
  rsh: "repeatSchemas",
  rch: "repeatChannels",
  ax: "useAttachmentIndex",
  mdx: "useMetadataIndex",
};

class Buffered {
  chunks = [];
  size = 0n;
  async write(buffer) {
    this.chunks.push(buffer.slice());
    this.size += BigInt(buffer.byteLength);
  }
  position() {
    return this.size;
  }
}

const bytes = (v) => Uint8Array.from(v.map(Number));

// The spec's record as @mcap/core's types.
function typed(record) {
  const f = Object.fromEntries(record.fields);
  switch (record.type) {
    case "Schema":
      return { id: Number(f.id), name: f.name, encoding: f.encoding, data: bytes(f.data) };
    case "Channel":
      return {
        id: Number(f.id),
        schemaId: Number(f.schema_id),
        topic: f.topic,
        messageEncoding: f.message_encoding,
        metadata: new Map(Object.entries(f.metadata)),
      };
    case "Message":
      return {
        channelId: Number(f.channel_id),
        sequence: Number(f.sequence),
        logTime: BigInt(f.log_time),
        publishTime: BigInt(f.publish_time),
        data: bytes(f.data),
      };
    case "Attachment":
      return {
        name: f.name,
        logTime: BigInt(f.log_time),
        createTime: BigInt(f.create_time),
        mediaType: f.media_type,
        data: bytes(f.data),
      };
    case "Metadata":
      return { name: f.name, metadata: new Map(Object.entries(f.metadata)) };
    default:
      return undefined;
  }
}

// A padded variant, record by record: the data section (schemas, channels and messages in one
// uncompressed chunk with `ch`, its message indexes with `mx`; attachments and metadata beside
// it), then the summary the features ask for, every record padded where the format allows it.
function writePadded(spec, features) {
  const has = (f) => features.includes(f);
  const file = new McapRecordBuilder({ padRecords: true });
  const chunk = has("ch") ? new McapRecordBuilder({ padRecords: true }) : undefined;
  const indexes = new Map();
  let start;
  let end;
  const schemas = [];
  const channels = [];
  const metadataIndexes = [];
  const attachmentIndexes = [];
  const counts = new Map();
  let messages = 0n;
  let attachments = 0;
  let metadata = 0;
  file.writeMagic();
  file.writeHeader({ profile: "", library: "" });
  for (const record of spec.records) {
    const r = typed(record);
    switch (record.type) {
      case "Schema":
        schemas.push(r);
        (chunk ?? file).writeSchema(r);
        break;
      case "Channel":
        channels.push(r);
        (chunk ?? file).writeChannel(r);
        break;
      case "Message":
        messages++;
        counts.set(r.channelId, (counts.get(r.channelId) ?? 0n) + 1n);
        start = start === undefined || r.logTime < start ? r.logTime : start;
        end = end === undefined || r.logTime > end ? r.logTime : end;
        if (chunk) {
          if (!indexes.has(r.channelId)) indexes.set(r.channelId, []);
          indexes.get(r.channelId).push([r.logTime, BigInt(chunk.length)]);
        }
        (chunk ?? file).writeMessage(r);
        break;
      case "Attachment": {
        attachments++;
        const offset = BigInt(file.length);
        const length = file.writeAttachment(r);
        if (has("ax")) {
          attachmentIndexes.push({
            offset,
            length,
            logTime: r.logTime,
            createTime: r.createTime,
            dataSize: BigInt(r.data.byteLength),
            name: r.name,
            mediaType: r.mediaType,
          });
        }
        break;
      }
      case "Metadata": {
        metadata++;
        const offset = BigInt(file.length);
        const length = file.writeMetadata(r);
        if (has("mdx")) metadataIndexes.push({ offset, length, name: r.name });
        break;
      }
      default:
        break;
    }
  }
  const chunkIndexes = [];
  if (chunk) {
    const chunkStartOffset = BigInt(file.length);
    const chunkLength = file.writeChunk({
      messageStartTime: start ?? 0n,
      messageEndTime: end ?? 0n,
      uncompressedSize: BigInt(chunk.length),
      uncompressedCrc: 0,
      compression: "",
      records: chunk.buffer,
    });
    const messageIndexOffsets = new Map();
    let messageIndexLength = 0n;
    if (has("mx")) {
      for (const [channelId, records] of indexes) {
        messageIndexOffsets.set(channelId, BigInt(file.length));
        messageIndexLength += file.writeMessageIndex({ channelId, records });
      }
    }
    if (has("chx")) {
      chunkIndexes.push({
        messageStartTime: start ?? 0n,
        messageEndTime: end ?? 0n,
        chunkStartOffset,
        chunkLength,
        messageIndexOffsets,
        messageIndexLength,
        compression: "",
        compressedSize: BigInt(chunk.length),
        uncompressedSize: BigInt(chunk.length),
      });
    }
  }
  file.writeDataEnd({ dataSectionCrc: 0 });
  const summaryStart = BigInt(file.length);
  const groups = [];
  const group = (opcode, write) => {
    const groupStart = BigInt(file.length);
    write();
    const groupLength = BigInt(file.length) - groupStart;
    if (groupLength > 0n) groups.push({ groupOpcode: opcode, groupStart, groupLength });
  };
  const { Opcode } = McapConstants;
  if (has("rsh")) group(Opcode.SCHEMA, () => schemas.forEach((r) => file.writeSchema(r)));
  if (has("rch")) group(Opcode.CHANNEL, () => channels.forEach((r) => file.writeChannel(r)));
  if (has("st")) {
    group(Opcode.STATISTICS, () =>
      file.writeStatistics({
        messageCount: messages,
        schemaCount: schemas.length,
        channelCount: channels.length,
        attachmentCount: attachments,
        metadataCount: metadata,
        chunkCount: chunk ? 1 : 0,
        messageStartTime: start ?? 0n,
        messageEndTime: end ?? 0n,
        channelMessageCounts: counts,
      }),
    );
  }
  group(Opcode.METADATA_INDEX, () => metadataIndexes.forEach((r) => file.writeMetadataIndex(r)));
  group(Opcode.ATTACHMENT_INDEX, () => attachmentIndexes.forEach((r) => file.writeAttachmentIndex(r)));
  group(Opcode.CHUNK_INDEX, () => chunkIndexes.forEach((r) => file.writeChunkIndex(r)));
  const hasSummary = BigInt(file.length) !== summaryStart;
  let summaryOffsetStart = 0n;
  if (has("sum") && groups.length > 0) {
    summaryOffsetStart = BigInt(file.length);
    groups.forEach((g) => file.writeSummaryOffset(g));
  }
  file.writeFooter({ summaryStart: hasSummary ? summaryStart : 0n, summaryOffsetStart, summaryCrc: 0 });
  file.writeMagic();
  return file.buffer;
}

// Foxglove's stream reader reads a padded file to its end, with as many messages as its JSON.
function checkWithStreamReader(name, data, spec) {
  const reader = new McapStreamReader({ validateCrcs: true });
  reader.append(data);
  let messages = 0;
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Message") messages++;
  }
  const listed = spec.records.filter((r) => r.type === "Message").length;
  if (!reader.done() || messages !== listed) {
    throw new Error(`${name}: McapStreamReader read ${messages} of ${listed} messages`);
  }
}

let written = 0;
let padded = 0;
for (const group of (await readdir(corpus, { withFileTypes: true })).filter((d) => d.isDirectory())) {
  const dir = join(corpus, group.name);
  for (const name of (await readdir(dir)).filter((n) => n.endsWith(".json")).sort()) {
    const spec = JSON.parse(await readFile(join(dir, name), "utf8"));
    const features = spec.meta.variant.features;
    const file = join(out, name.replace(/\.json$/, ".mcap"));
    if (features.includes("pad")) {
      const data = writePadded(spec, features);
      checkWithStreamReader(name, data, spec);
      await writeFile(file, data);
      console.log(file);
      written++;
      padded++;
      continue;
    }
    const options = Object.fromEntries(Object.values(OPTIONS).map((o) => [o, false]));
    for (const f of features) {
      if (!OPTIONS[f]) throw new Error(`${name}: unknown feature ${f}`);
      options[OPTIONS[f]] = true;
    }
    const writable = new Buffered();
    const writer = new McapWriter({ writable, ...options });
    const schemas = new Map([[0, 0]]);
    const channels = new Map();
    for (const record of spec.records) {
      const f = Object.fromEntries(record.fields);
      switch (record.type) {
        case "Header":
          await writer.start({ library: f.library, profile: f.profile });
          break;
        case "Schema":
          if (!schemas.has(Number(f.id))) {
            schemas.set(Number(f.id), await writer.registerSchema({ name: f.name, encoding: f.encoding, data: bytes(f.data) }));
          }
          break;
        case "Channel":
          if (!channels.has(Number(f.id))) {
            channels.set(
              Number(f.id),
              await writer.registerChannel({
                schemaId: schemas.get(Number(f.schema_id)),
                topic: f.topic,
                messageEncoding: f.message_encoding,
                metadata: new Map(Object.entries(f.metadata)),
              }),
            );
          }
          break;
        case "Message":
          await writer.addMessage({
            channelId: channels.get(Number(f.channel_id)),
            sequence: Number(f.sequence),
            logTime: BigInt(f.log_time),
            publishTime: BigInt(f.publish_time),
            data: bytes(f.data),
          });
          break;
        case "Attachment":
          await writer.addAttachment({
            name: f.name,
            logTime: BigInt(f.log_time),
            createTime: BigInt(f.create_time),
            mediaType: f.media_type,
            data: bytes(f.data),
          });
          break;
        case "Metadata":
          await writer.addMetadata({ name: f.name, metadata: new Map(Object.entries(f.metadata)) });
          break;
        default:
          // Data end, footer, indexes, statistics, summary offsets: the writer's own.
          break;
      }
    }
    await writer.end();
    await writeFile(file, Buffer.concat(writable.chunks));
    console.log(file);
    written++;
  }
}
console.log(`written ${written}, ${padded} of them padded`);
