// Read a gvtlink MCAP log with @mcap/core (not the Python `mcap` package) and decode the first
// sample block of TOPIC with protobufjs, using only the FileDescriptorSet stored in the file.
//
// usage: node read_block.mjs FILE.mcap TOPIC
// prints one JSON line: {"schema", "encoding", "schema_encoding", "chunk_compression", "messages",
//                        "first": {stream, first_index, sample_rate, n_channels, n_samples, data[0:6]}, "sum"}
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { decompress as zstdDecompress } from "fzstd";
import protobuf from "protobufjs";
import "protobufjs/ext/descriptor/index.js"; // adds Root.fromDescriptor

const [file, topic] = process.argv.slice(2);
if (!file || !topic) {
  process.stderr.write("usage: node read_block.mjs FILE.mcap TOPIC\n");
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

  let count = 0;
  let first = null;
  let sum = 0;
  for await (const msg of reader.readMessages({ topics: [topic], validateCrcs: true })) {
    count += 1;
    if (first === null) {
      const obj = Type.toObject(Type.decode(msg.data), { longs: String, defaults: true, arrays: true });
      for (const x of obj.data) sum += x;
      const asInt = (v) => (Number.isSafeInteger(Number(v)) ? Number(v) : String(v));
      first = {
        stream: obj.stream,
        first_index: asInt(obj.first_index),
        sample_rate: obj.sample_rate,
        n_channels: obj.n_channels,
        n_samples: obj.n_samples,
        n_data: obj.data.length,
        data: obj.data.slice(0, 6),
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
      sum,
    }) + "\n",
  );
} finally {
  await handle.close();
}
