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
// channels repeated in the summary, ax attachment index, mdx metadata index). `pad` (records
// with extra trailing bytes) is not something McapWriter can write: those variants are skipped.
// Prints one line per file written (OUT_DIR/VARIANT.mcap) and the count skipped.

import { mkdir, readdir, readFile, writeFile } from "node:fs/promises";
import { join } from "node:path";
import { McapWriter } from "@mcap/core";

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
let written = 0;
let skipped = 0;
for (const group of (await readdir(corpus, { withFileTypes: true })).filter((d) => d.isDirectory())) {
  const dir = join(corpus, group.name);
  for (const name of (await readdir(dir)).filter((n) => n.endsWith(".json")).sort()) {
    const spec = JSON.parse(await readFile(join(dir, name), "utf8"));
    const features = spec.meta.variant.features;
    if (features.includes("pad")) {
      skipped++;
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
    const file = join(out, name.replace(/\.json$/, ".mcap"));
    await writeFile(file, Buffer.concat(writable.chunks));
    console.log(file);
    written++;
  }
}
console.log(`written ${written}, skipped ${skipped} padded variants`);
