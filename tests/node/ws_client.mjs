// node ws_client.mjs URL TIMEOUT_S [--stay] TOPIC_PATTERN... -> one JSON line: Foxglove's own WebSocket client
// (@foxglove/ws-protocol) subscribes to every advertised channel whose topic matches one of the patterns
// (regular expressions) and decodes and validates what arrives, until each pattern has a message or the time
// is up (--stay: until the time is up, or SIGTERM; it then reports message and byte counts, as a viewer would
// load the bridge). Exit status 1 when a pattern got nothing or a message does not decode.
import pkg from "@foxglove/ws-protocol";
import WebSocket from "ws";
import { DECODABLE, formProblems, foxgloveReadableProblems, validator } from "./common.mjs";

const { FoxgloveClient } = pkg;
const [url, timeoutS, ...rest] = process.argv.slice(2);
const stay = rest[0] === "--stay";
const patterns = stay ? rest.slice(1) : rest;
const started = Date.now();
let bytes = 0;
const wanted = patterns.map((p) => new RegExp(p));
const got = Object.fromEntries(patterns.map((p) => [p, 0]));
const perTopic = {};
const problems = [];
const subs = new Map();
const decoder = new TextDecoder("utf-8", { fatal: true });
let advertised = 0;
let serverName = null;
let opened = false;

// foxglove-sdk servers speak "foxglove.sdk.v1" (the same protocol as "foxglove.websocket.v1" under a new name)
const client = new FoxgloveClient({ ws: new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]) });
const done = (code) => {
  const seconds = (Date.now() - started) / 1000;
  const messages = Object.values(perTopic).reduce((a, b) => a + b, 0);
  console.log(JSON.stringify({ client: "@foxglove/ws-protocol", server: serverName, opened, advertised,
                               subscribed: subs.size, got, perTopic, messages, bytes, seconds,
                               problems: problems.slice(0, 20) }));
  try { client.close(); } catch { /* closing anyway */ }
  process.exit(code);
};
const verdict = () => (problems.length === 0 && Object.values(got).every((n) => n > 0) ? 0 : 1);
const timer = setTimeout(() => done(stay ? verdict() : 1), Number(timeoutS) * 1000);
process.on("SIGTERM", () => done(verdict()));
client.on("open", () => { opened = true; });
client.on("error", (e) => problems.push(`socket: ${e?.message ?? e}`));
client.on("serverInfo", (info) => { serverName = info.name; });
client.on("advertise", (channels) => {
  advertised += channels.length;
  for (const ch of channels) {
    if (!wanted.some((re) => re.test(ch.topic))) continue;
    if (!DECODABLE.has(ch.encoding)) problems.push(`${ch.topic}: encoding ${ch.encoding}`);
    const unreadable = foxgloveReadableProblems(JSON.parse(ch.schema));
    if (unreadable.length > 0) problems.push(`${ch.topic}: schema not readable by Foxglove: ${unreadable.slice(0, 3)}`);
    subs.set(client.subscribe(ch.id), ch);
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const ch = subs.get(subscriptionId);
  if (!ch) return;
  perTopic[ch.topic] = (perTopic[ch.topic] ?? 0) + 1;
  bytes += data.byteLength;
  let msg;
  try {
    msg = JSON.parse(decoder.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)));
  } catch (e) {
    problems.push(`${ch.topic}: not JSON: ${e.message}`);
    return;
  }
  const v = validator(ch.schemaName, ch.schema);
  if (!v(msg)) problems.push(`${ch.topic}: fails ${ch.schemaName}: ${JSON.stringify(v.errors?.slice(0, 2))}`);
  problems.push(...formProblems(ch.topic, ch.schemaName, msg));
  patterns.forEach((p, i) => { if (wanted[i].test(ch.topic)) got[p]++; });
  if (!stay && Object.values(got).every((n) => n > 0)) {
    clearTimeout(timer);
    done(problems.length === 0 ? 0 : 1);
  }
});
