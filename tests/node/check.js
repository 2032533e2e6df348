// Test-only: reads a canfdi MCAP log with third-party JavaScript readers and prints one JSON
// object (tests/integration/test_third_party_readers.py checks it):
// - Foxglove's @mcap/core: the streaming reader (chunk CRCs validated) and the indexed reader
//   (summary, chunk indexes, message indexes; CRCs validated), messages per topic;
// - Lichtblick's parseJsonSchema (vendor/, the JSON-schema parser of the last open-source
//   Foxglove Studio's lineage), run on every jsonschema channel's schema and on its messages;
// - Foxglove's ROS 2 libraries, as Foxglove opens an MCAP channel of schema encoding "ros2msg"
//   and message encoding "cdr": @foxglove/rosmsg's parse(text, { ros2: true }) on the schema,
//   @foxglove/rosmsg2-serialization's MessageReader on every message (out.ros2: per channel,
//   the fields of each type, the messages decoded, the first and last of them as plain JSON;
//   with --rows, out.rows: every decoded message of each such topic, in file order);
// - @foxglove/schemas' own foxglove.Log JSON schema, to compare with the log's.
"use strict";
const fs = require("fs");
const path = require("path");
const ts = require("typescript");
const { McapStreamReader, McapIndexedReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const foxgloveSchemas = require("@foxglove/schemas/jsonschema");
const { parse: parseRosMsg } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

function loadParser() {
  const source = fs.readFileSync(path.join(__dirname, "vendor", "parseJsonSchema.ts"), "utf8");
  const js = ts.transpileModule(source, {
    compilerOptions: { module: ts.ModuleKind.CommonJS, target: ts.ScriptTarget.ES2020 },
  }).outputText;
  const module = { exports: {} };
  new Function("require", "module", "exports", js)(require, module, module.exports);
  return module.exports.parseJsonSchema;
}

// A decoded message as JSON: int64s (BigInt) as numbers where exact, else as decimal strings;
// NaN and the infinities, which JSON has not, as "NaN", "Infinity", "-Infinity".
function plain(value) {
  if (typeof value === "bigint") {
    return Number.isSafeInteger(Number(value)) ? Number(value) : value.toString();
  }
  if (typeof value === "number") return Number.isFinite(value) ? value : String(value);
  if (ArrayBuffer.isView(value) || Array.isArray(value)) return Array.from(value, plain);
  if (value !== null && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}

// A ros2msg schema as Foxglove reads it: the root type under the schema's name, each other
// type under its own; each field's name and type ("float64", "canfdi/SampleInput", "int32[]").
function parseRos2(schema, text) {
  const definitions = parseRosMsg(text, { ros2: true });
  const fields = {};
  definitions.forEach((def, i) => {
    const name = i === 0 ? schema.name : def.name;
    fields[name] = def.definitions.filter((f) => !f.isConstant).map((f) => [
      f.name,
      f.type + (f.isArray ? `[${f.arrayUpperBound != null ? "<=" + f.arrayUpperBound : f.arrayLength ?? ""}]` : ""),
    ]);
  });
  return { definitions, fields };
}

async function main() {
  const args = process.argv.slice(2);
  const allRows = args.includes("--rows");
  const file = args.find((a) => a !== "--rows");
  const bytes = new Uint8Array(fs.readFileSync(file));
  const decompressHandlers = await loadDecompressHandlers();
  const parseJsonSchema = loadParser();
  const out = { stream: {}, indexed: {}, schemas: {}, ros2: [], errors: [] };
  if (allRows) out.rows = {};

  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(bytes);
  const channels = new Map();
  const schemas = new Map();
  const decoders = new Map();
  const errorsPerChannel = new Map();
  let record;
  while ((record = stream.nextRecord()) !== undefined) {
    if (record.type === "Schema") schemas.set(record.id, record);
    else if (record.type === "Channel") {
      if (channels.has(record.id)) continue; // the summary repeats the channels
      channels.set(record.id, record);
      const schema = schemas.get(record.schemaId);
      try {
        if (schema === undefined) throw new Error(`no schema (schema id ${record.schemaId})`);
        const text = new TextDecoder().decode(schema.data);
        if (schema.encoding === "ros2msg" && record.messageEncoding === "cdr") {
          const { definitions, fields } = parseRos2(schema, text);
          const reader = new MessageReader(definitions);
          const seen = { topic: record.topic, schema: schema.name, fields, messages: 0 };
          out.ros2.push(seen);
          decoders.set(record.id, (data) => {
            const message = plain(reader.readMessage(data));
            if (reader.lastReadHadTrailingBytes()) {
              throw new Error(`${reader.lastReadByteLength()} of ${data.byteLength} bytes read`);
            }
            seen.messages += 1;
            seen.first ??= message;
            seen.last = message;
            if (allRows) (out.rows[seen.topic] ??= []).push(message);
          });
          out.schemas[record.topic] = {
            name: schema.name,
            encoding: schema.encoding,
            types: Object.fromEntries(Object.entries(fields).map(([k, v]) => [k, v.map((f) => f[0])])),
          };
        } else if (schema.encoding === "jsonschema" && record.messageEncoding === "json") {
          const parsed = parseJsonSchema(JSON.parse(text), schema.name);
          const post = parsed.postprocessValue;
          decoders.set(record.id, (data) => post(JSON.parse(new TextDecoder().decode(data))));
          out.schemas[record.topic] = {
            name: schema.name,
            encoding: schema.encoding,
            types: Object.fromEntries([...parsed.datatypes].map(([k, v]) => [k, v.definitions.map((d) => d.name)])),
          };
        } else {
          throw new Error(`schema encoding ${schema.encoding} with message encoding ${record.messageEncoding}`);
        }
      } catch (err) {
        out.errors.push(`${record.topic}: ${err.message}`);
      }
    } else if (record.type === "Message") {
      const topic = channels.get(record.channelId).topic;
      out.stream[topic] = (out.stream[topic] ?? 0) + 1;
      const decode = decoders.get(record.channelId);
      if (decode) {
        try {
          decode(record.data);
        } catch (err) {
          if (errorsPerChannel.get(record.channelId) === undefined) {
            out.errors.push(`${topic}: message at ${record.logTime}: ${err.message}`);
          }
          errorsPerChannel.set(record.channelId, (errorsPerChannel.get(record.channelId) ?? 0) + 1);
        }
      }
    }
  }
  if (!stream.done()) out.errors.push("stream reader: file not complete");
  for (const [id, n] of errorsPerChannel) {
    if (n > 1) out.errors.push(`${channels.get(id).topic}: ${n} messages not decoded`);
  }

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
