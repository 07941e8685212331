// Read a gvtlink MCAP log with @mcap/core (not the Python `mcap` package) and decode the sample blocks
// of TOPIC with protobufjs, using only the FileDescriptorSet stored in the file.
//
// usage: node read_block.mjs FILE.mcap TOPIC [FIELD]
// With FIELD, resolves the Foxglove-style message path TOPIC.FIELD (no index, no slice, no filter) in
// every message and concatenates the arrays: one channel's samples over the whole log ("series").
// prints one JSON line: {"schema", "encoding", "schema_encoding", "chunk_compression", "messages",
//                        "first": {stream, first_index, sample_rate, n_channels, n_samples, fields},
//                        "series": [...] (with FIELD), "series_lengths": [...], "metadata": {...}}
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { decompress as zstdDecompress } from "fzstd";
import protobuf from "protobufjs";
import "protobufjs/ext/descriptor/index.js"; // adds Root.fromDescriptor

const [file, topic, field] = process.argv.slice(2);
if (!file || !topic) {
  process.stderr.write("usage: node read_block.mjs FILE.mcap TOPIC [FIELD]\n");
  process.exit(2);
}

const handle = await open(file, "r");
try {
  const readable = {
    size: async () => BigInt((await handle.stat()).size),
    read: async (offset, size) => {
      const buf = new Uint8Array(Number(size));
      let done = 0;
      while (done < buf.length) {
        const { bytesRead } = await handle.read(buf, done, buf.length - done, Number(offset) + done);
        if (bytesRead === 0) throw new Error(`short read at ${Number(offset) + done}`);
        done += bytesRead;
      }
      return buf;
    },
  };
  const decompressHandlers = {
    zstd: (buffer, decompressedSize) => {
      const out = zstdDecompress(buffer, new Uint8Array(Number(decompressedSize)));
      if (out.length !== Number(decompressedSize)) throw new Error(`zstd: got ${out.length} bytes, expected ${decompressedSize}`);
      return out;
    },
  };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });

  const channel = [...reader.channelsById.values()].find((c) => c.topic === topic);
  if (!channel) throw new Error(`topic ${topic} not in ${file}`);
  const schema = reader.schemasById.get(channel.schemaId);
  if (!schema) throw new Error(`channel ${topic} has no schema`);
  if (schema.encoding !== "protobuf") throw new Error(`schema encoding ${schema.encoding}, expected protobuf`);

  const root = protobuf.Root.fromDescriptor(schema.data, { keepCase: true }); // field names as in the .proto
  const Type = root.lookupType(schema.name);
  const compressions = [...new Set(reader.chunkIndexes.map((c) => c.compression))];

  if (field !== undefined && !Type.fields[field]) throw new Error(`${schema.name} has no field ${field}`);
  if (field !== undefined && !Type.fields[field].repeated) throw new Error(`${topic}.${field} is not an array`);

  let count = 0;
  let first = null;
  const series = [];
  const seriesLengths = [];
  for await (const msg of reader.readMessages({ topics: [topic], validateCrcs: true })) {
    count += 1;
    const obj = Type.toObject(Type.decode(msg.data), { longs: String, defaults: true, arrays: true });
    if (field !== undefined) {
      const values = obj[field]; // the message path TOPIC.FIELD: one plain array per message
      for (const x of values) series.push(x);
      seriesLengths.push(values.length);
    }
    if (first === null) {
      const asInt = (v) => (Number.isSafeInteger(Number(v)) ? Number(v) : String(v));
      first = {
        stream: obj.stream,
        first_index: asInt(obj.first_index),
        sample_rate: obj.sample_rate,
        n_channels: obj.n_channels,
        n_samples: obj.n_samples,
        fields: Type.fieldsArray.map((f) => f.name),
      };
    }
  }
  process.stdout.write(
    JSON.stringify({
      schema: schema.name,
      schema_encoding: schema.encoding,
      encoding: channel.messageEncoding,
      chunk_compression: compressions,
      messages: count,
      first,
      series,
      series_lengths: seriesLengths,
      metadata: Object.fromEntries(channel.metadata),
    }) + "\n",
  );
} finally {
  await handle.close();
}
