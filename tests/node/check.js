// Test-only: reads a canfdi MCAP log with third-party JavaScript readers and prints one JSON
// object (tests/integration/test_third_party_readers.py checks it):
// - Foxglove's @mcap/core: the streaming reader (chunk CRCs validated) and the indexed reader
//   (summary, chunk indexes, message indexes; CRCs validated), messages per topic;
// - Lichtblick's parseJsonSchema (vendor/, the JSON-schema parser of the last open-source
//   Foxglove Studio's lineage), run on every channel's schema and on its messages;
// - @foxglove/schemas' own foxglove.Log JSON schema, to compare with the log's.
"use strict";
const fs = require("fs");
const path = require("path");
const ts = require("typescript");
const { McapStreamReader, McapIndexedReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const foxgloveSchemas = require("@foxglove/schemas/jsonschema");

function loadParser() {
  const source = fs.readFileSync(path.join(__dirname, "vendor", "parseJsonSchema.ts"), "utf8");
  const js = ts.transpileModule(source, {
    compilerOptions: { module: ts.ModuleKind.CommonJS, target: ts.ScriptTarget.ES2020 },
  }).outputText;
  const module = { exports: {} };
  new Function("require", "module", "exports", js)(require, module, module.exports);
  return module.exports.parseJsonSchema;
}

async function main() {
  const file = process.argv[2];
  const bytes = new Uint8Array(fs.readFileSync(file));
  const decompressHandlers = await loadDecompressHandlers();
  const parseJsonSchema = loadParser();
  const out = { stream: {}, indexed: {}, schemas: {}, errors: [] };

  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(bytes);
  const channels = new Map();
  const schemas = new Map();
  const parsers = new Map();
  let record;
  while ((record = stream.nextRecord()) !== undefined) {
    if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") {
      if (channels.has(record.id)) continue; // the summary repeats the channels
      channels.set(record.id, record);
      const schema = schemas.get(record.schemaId);
      const text = new TextDecoder().decode(schema.data);
      try {
        const parsed = parseJsonSchema(JSON.parse(text), schema.name);
        parsers.set(record.id, parsed.postprocessValue);
        out.schemas[record.topic] = {
          name: schema.name,
          types: Object.fromEntries([...parsed.datatypes].map(([k, v]) => [k, v.definitions.map((d) => d.name)])),
        };
      } catch (err) {
        out.errors.push(`${record.topic}: ${err.message}`);
      }
    } else if (record.type === "Message") {
      const topic = channels.get(record.channelId).topic;
      out.stream[topic] = (out.stream[topic] ?? 0) + 1;
      const post = parsers.get(record.channelId);
      if (post) post(JSON.parse(new TextDecoder().decode(record.data)));
    }
  }
  if (!stream.done()) out.errors.push("stream reader: file not complete");

  const readable = {
    size: async () => BigInt(bytes.length),
    read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)),
  };
  const indexed = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  for await (const message of indexed.readMessages({ validateCrcs: true })) {
    const topic = indexed.channelsById.get(message.channelId).topic;
    out.indexed[topic] = (out.indexed[topic] ?? 0) + 1;
  }
  out.dataSectionCrc = indexed.dataSectionCrc ?? 0;
  out.summaryStart = Number(indexed.footer.summaryStart);
  out.chunkIndexes = indexed.chunkIndexes.length;
  out.foxgloveLog = foxgloveSchemas.Log;
  console.log(JSON.stringify(out));
}

main().catch((err) => {
  console.error(err.stack || String(err));
  process.exit(1);
});
