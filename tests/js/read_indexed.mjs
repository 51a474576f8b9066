// Reads every message of MCAP files with @mcap/core's McapIndexedReader (the reader Foxglove uses for
// files with a summary) and validates each JSON message against its channel's JSON schema with ajv.
// Usage: node read_indexed.mjs FILE...   Prints one JSON line per file: topics, message counts, errors.
import { readFile } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import * as zstd from "@foxglove/wasm-zstd";
import Ajv2020 from "ajv/dist/2020.js";

function readableOf(bytes) {
  return {
    size: async () => BigInt(bytes.byteLength),
    read: async (offset, size) => bytes.subarray(Number(offset), Number(offset + size)),
  };
}

async function check(path) {
  const bytes = new Uint8Array(await readFile(path));
  const reader = await McapIndexedReader.Initialize({
    readable: readableOf(bytes),
    decompressHandlers: { zstd: (buffer, size) => zstd.decompress(buffer, Number(size)) },
  });
  const ajv = new Ajv2020({ strict: false, allErrors: false });
  const validators = new Map();
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    if (!schema || schema.encoding !== "jsonschema" || channel.messageEncoding !== "json") {
      throw new Error(`channel ${channel.topic}: expected a JSON channel with a JSON schema`);
    }
    validators.set(id, { topic: channel.topic, schemaName: schema.name,
                         validate: ajv.compile(JSON.parse(new TextDecoder().decode(schema.data))) });
  }
  const counts = {};
  const errors = [];
  let previous = -1n;
  for await (const message of reader.readMessages()) {
    const { topic, schemaName, validate } = validators.get(message.channelId);
    counts[topic] = (counts[topic] ?? 0) + 1;
    if (message.logTime < previous) errors.push(`${topic}: log time goes backwards`);
    previous = message.logTime;
    const value = JSON.parse(new TextDecoder().decode(message.data));
    if (!validate(value) && errors.length < 20) {
      errors.push(`${topic} (${schemaName}) seq ${message.sequence}: ${ajv.errorsText(validate.errors)}`);
    }
  }
  const schemas = Object.fromEntries([...validators.values()].map((v) => [v.topic, v.schemaName]));
  const metadata = [...reader.metadataIndexes].map((m) => m.name);
  return { path, counts, schemas, metadata, messageCount: Number(reader.statistics?.messageCount ?? -1),
           errors };
}

await zstd.isLoaded;
let failed = false;
for (const path of process.argv.slice(2)) {
  try {
    console.log(JSON.stringify(await check(path)));
  } catch (error) {
    failed = true;
    console.log(JSON.stringify({ path, fatal: String(error && error.message ? error.message : error) }));
  }
}
process.exit(failed ? 1 : 0);
