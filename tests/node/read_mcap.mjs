// node read_mcap.mjs RUN.mcap -> one JSON line: what the reference MCAP reader (@mcap/core) finds in a recording.
// Every channel's encoding must be one Foxglove decodes, every message must parse as JSON and validate against
// its channel's schema, and the Foxglove-typed channels must be well formed. Exit status 1 on any problem.
import { McapIndexedReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";
import { open } from "node:fs/promises";
import { DECODABLE, formProblems, foxgloveReadableProblems, sameAsFoxglove, validator } from "./common.mjs";

const path = process.argv[2];
const fh = await open(path, "r");
const readable = {
  size: async () => BigInt((await fh.stat()).size),
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await fh.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: await loadDecompressHandlers() });
const problems = [];
const encodings = {};
const perTopic = {};
const perSchema = {};
const foxgloveSchemasMatch = {};
for (const ch of reader.channelsById.values()) {
  encodings[ch.messageEncoding] = (encodings[ch.messageEncoding] ?? 0) + 1;
  if (!DECODABLE.has(ch.messageEncoding)) problems.push(`${ch.topic}: encoding ${ch.messageEncoding} Foxglove does not decode`);
  const sc = reader.schemasById.get(ch.schemaId);
  if (!sc || sc.encoding !== "jsonschema") problems.push(`${ch.topic}: no JSON Schema`);
  else {
    const unreadable = foxgloveReadableProblems(JSON.parse(new TextDecoder().decode(sc.data)));
    if (unreadable.length > 0) problems.push(`${ch.topic}: schema ${sc.name} not readable by Foxglove: ${unreadable.slice(0, 3)}`);
  }
  if (sc?.name.startsWith("foxglove.")) {
    foxgloveSchemasMatch[sc.name] = sameAsFoxglove(sc.name, new TextDecoder().decode(sc.data));
    if (!foxgloveSchemasMatch[sc.name]) problems.push(`${ch.topic}: schema ${sc.name} differs from @foxglove/schemas`);
  }
}
const decoder = new TextDecoder("utf-8", { fatal: true });
let messages = 0;
for await (const m of reader.readMessages()) {
  messages++;
  const ch = reader.channelsById.get(m.channelId);
  const sc = reader.schemasById.get(ch.schemaId);
  perTopic[ch.topic] = (perTopic[ch.topic] ?? 0) + 1;
  perSchema[sc.name] = (perSchema[sc.name] ?? 0) + 1;
  let msg;
  try {
    msg = JSON.parse(decoder.decode(m.data));
  } catch (e) {
    problems.push(`${ch.topic}: message ${messages} is not JSON: ${e.message}`);
    continue;
  }
  const v = validator(sc.name, decoder.decode(sc.data));
  if (!v(msg)) problems.push(`${ch.topic}: message ${messages} fails ${sc.name}: ${JSON.stringify(v.errors?.slice(0, 2))}`);
  problems.push(...formProblems(ch.topic, sc.name, msg));
}
await fh.close();
console.log(JSON.stringify({
  reader: "@mcap/core", profile: reader.header.profile, channels: reader.channelsById.size, messages,
  encodings, perSchema, perTopic, foxgloveSchemasMatch, problems: problems.slice(0, 20), problemCount: problems.length,
}));
process.exit(problems.length === 0 ? 0 : 1);
