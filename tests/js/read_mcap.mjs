// Read an MCAP file with @mcap/core, the reference TypeScript implementation, and print a
// JSON summary: per topic the message count, message encoding and schema name, plus the
// metadata names. Indexed (complete) files go through McapIndexedReader; with --stream,
// McapStreamReader reads record by record (and must reach the end cleanly).
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";
import { open, readFile } from "node:fs/promises";

const [path, mode] = process.argv.slice(2);
const decompressHandlers = await loadDecompressHandlers();
const topics = {};
const metadata = [];
const add = (channel, schema) => {
  const t = (topics[channel.topic] ??= { count: 0, encoding: channel.messageEncoding, schemas: [] });
  t.count += 1;
  const name = schema ? schema.name : "";
  if (!t.schemas.includes(name)) t.schemas.push(name);
};

if (mode === "--stream") {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(await readFile(path));
  const schemas = new Map();
  const channels = new Map();
  let rec;
  while ((rec = reader.nextRecord())) {
    if (rec.type === "Schema") schemas.set(rec.id, rec);
    else if (rec.type === "Channel") channels.set(rec.id, rec);
    else if (rec.type === "Metadata") metadata.push(rec.name);
    else if (rec.type === "Message") {
      const ch = channels.get(rec.channelId);
      add(ch, schemas.get(ch.schemaId));
    }
  }
  if (!reader.done()) throw new Error("stream ended before the MCAP footer");
} else {
  const handle = await open(path, "r");
  const reader = await McapIndexedReader.Initialize({ readable: new FileHandleReadable(handle), decompressHandlers });
  for await (const m of reader.readMessages()) {
    const ch = reader.channelsById.get(m.channelId);
    add(ch, reader.schemasById.get(ch.schemaId));
  }
  for await (const md of reader.readMetadata()) metadata.push(md.name);
  await handle.close();
}
console.log(JSON.stringify({ topics, metadata }));
