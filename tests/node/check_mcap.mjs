// Reads an MCAP file tofu wrote with the reference reader (@mcap/core) and checks it
// against the run directory it came from:
//  1. the indexed reader (summary, chunk and message indexes, CRCs) and the stream reader
//     (record by record, CRCs) both read it without error and agree on the messages;
//  2. every message parses as JSON and validates against the schema embedded in the
//     file, and every message of a foxglove.* schema also against @foxglove/schemas'
//     official JSON schema of that name;
//  3. the channels are exactly those the run directory implies, each with the message
//     count its files imply (counted here from the files, independently of tofu);
//  4. the Statistics record matches what was read.
//  5. with LAYOUT (a Foxglove layout, docs/foxglove_layout.json), every topic the layout's
//     panels name is a channel of the file, so the layout opens on data.
// Usage: node check_mcap.mjs FILE.mcap RUN_DIR [LAYOUT]. Exit 0 when all hold, 1 otherwise.
import fs from "node:fs";
import path from "node:path";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import * as foxglove from "@foxglove/schemas/jsonschema.js";
import zstd from "@foxglove/wasm-zstd";
import Ajv2020 from "ajv/dist/2020.js";

const [mcapPath, runDir, layoutPath] = process.argv.slice(2);
if (!mcapPath || !runDir) {
  console.error("usage: node check_mcap.mjs FILE.mcap RUN_DIR");
  process.exit(2);
}

const failures = [];
const fail = (message) => {
  if (failures.length < 40) failures.push(message);
};

await zstd.isLoaded;
const decompressHandlers = {
  zstd: (buffer, decompressedSize) => zstd.decompress(buffer, Number(decompressedSize)),
};

// ---- 1. both readers ----
const bytes = fs.readFileSync(mcapPath);
const readable = {
  size: async () => BigInt(bytes.length),
  read: async (offset, length) => bytes.subarray(Number(offset), Number(offset + length)),
};
const indexed = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const indexedMessages = [];
for await (const message of indexed.readMessages({ validateCrcs: true })) indexedMessages.push(message);

const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(bytes);
const streamMessages = [];
const streamChannels = new Map();
let record;
let sawFooter = false;
while ((record = stream.nextRecord()) !== undefined) {
  if (record.type === "Message") streamMessages.push(record);
  if (record.type === "Channel") streamChannels.set(record.id, record);
  if (record.type === "Footer") sawFooter = true;
}
if (!stream.done()) fail("stream reader: file not read to its end");
if (!sawFooter) fail("stream reader: no footer");
if (streamMessages.length !== indexedMessages.length) {
  fail(`indexed reader read ${indexedMessages.length} messages, stream reader ${streamMessages.length}`);
}

// ---- 2. schemas ----
const ajv = new Ajv2020({ allErrors: false, strict: false });
const embedded = new Map();  // schema id -> validate()
for (const [id, schema] of indexed.schemasById) {
  if (schema.encoding !== "jsonschema") fail(`schema ${schema.name}: encoding ${schema.encoding}, expected jsonschema`);
  const text = new TextDecoder().decode(schema.data);
  try {
    embedded.set(id, ajv.compile(JSON.parse(text)));
  } catch (e) {
    fail(`schema ${schema.name}: does not compile: ${e.message}`);
  }
}
const official = new Map();  // foxglove.X -> validate()
const officialFor = (name) => {
  if (!official.has(name)) {
    const schema = foxglove[name.slice("foxglove.".length)];
    official.set(name, schema ? ajv.compile(schema) : undefined);
  }
  return official.get(name);
};
const counts = new Map();  // topic -> messages
const decoder = new TextDecoder();
let validatedOfficial = 0;
for (const message of indexedMessages) {
  const channel = indexed.channelsById.get(message.channelId);
  if (!channel) {
    fail(`message on unknown channel ${message.channelId}`);
    continue;
  }
  counts.set(channel.topic, (counts.get(channel.topic) ?? 0) + 1);
  if (channel.messageEncoding !== "json") fail(`${channel.topic}: encoding ${channel.messageEncoding}`);
  let value;
  try {
    value = JSON.parse(decoder.decode(message.data));
  } catch (e) {
    fail(`${channel.topic} #${message.sequence}: not JSON: ${e.message}`);
    continue;
  }
  const schema = indexed.schemasById.get(channel.schemaId);
  const validate = embedded.get(channel.schemaId);
  if (validate && !validate(value)) {
    fail(`${channel.topic} #${message.sequence}: fails its schema ${schema.name}: ${ajv.errorsText(validate.errors)}`);
  }
  if (schema && schema.name.startsWith("foxglove.")) {
    const check = officialFor(schema.name);
    if (!check) {
      fail(`${channel.topic}: ${schema.name} is not a schema of @foxglove/schemas`);
    } else if (!check(value)) {
      fail(`${channel.topic} #${message.sequence}: fails @foxglove/schemas ${schema.name}: ${ajv.errorsText(check.errors)}`);
    } else {
      ++validatedOfficial;
    }
  }
}

// ---- 3. channels and counts from the run directory ----
const dataRows = (file) => {
  const lines = fs.readFileSync(file, "utf8").split("\n").filter((l) => l.length > 0);
  return lines.filter((l) => !l.startsWith("#")).map((l) => l.split(","));
};
const expected = new Map();  // topic -> exact count
const atMost = new Map();    // topic -> upper bound (poses that could be placed in W)
const gt = dataRows(path.join(runDir, "groundtruth.csv")).length;
expected.set("/tf", gt);
expected.set("/groundtruth", gt);
expected.set("/scene", 1);
const sensorsDir = path.join(runDir, "sensors");
if (fs.existsSync(sensorsDir)) {
  for (const f of fs.readdirSync(sensorsDir).filter((f) => f.endsWith(".csv"))) {
    const name = f.slice(0, -4);
    const rows = dataRows(path.join(sensorsDir, f));
    const header = fs.readFileSync(path.join(sensorsDir, f), "utf8").split("\n", 1)[0];
    expected.set(`/sensors/${name}`, rows.length);
    if (!header.includes("w_RS_S_x")) atMost.set(`/sensors/${name}/world`, rows.length);
  }
}
for (const f of fs.readdirSync(runDir)) {
  if (!f.startsWith("estimate_") || !f.endsWith(".csv") || f.endsWith("_errors.csv")) continue;
  const stem = f.slice(0, -4);
  let method = stem.slice("estimate_".length);
  const json = path.join(runDir, `${stem}.json`);
  if (fs.existsSync(json)) method = JSON.parse(fs.readFileSync(json, "utf8")).method ?? method;
  const rows = dataRows(path.join(runDir, f));
  expected.set(`/estimates/${method}`, rows.length);
  atMost.set(`/estimates/${method}/world`, rows.length);
}
const errorsCsv = path.join(runDir, "errors.csv");
if (fs.existsSync(errorsCsv)) {
  for (const row of dataRows(errorsCsv)) {
    // errors.csv rows with a finite position error (the others are invalid outputs).
    if (!Number.isFinite(Number(row[2])) || row[2] === "") continue;
    const topic = `/errors/${row[1]}`;
    expected.set(topic, (expected.get(topic) ?? 0) + 1);
  }
}
const methodsByStem = new Map();
for (const f of fs.readdirSync(runDir)) {
  const m = f.match(/^estimate_(.+)\.json$/);
  if (m) methodsByStem.set(m[1], JSON.parse(fs.readFileSync(path.join(runDir, f), "utf8")).method ?? m[1]);
}
if (!fs.existsSync(errorsCsv)) {
  // Without errors.csv, each method's estimate_<m>_errors.csv (t, position error, ...).
  for (const f of fs.readdirSync(runDir)) {
    const m = f.match(/^estimate_(.+)_errors\.csv$/);
    if (!m) continue;
    const rows = dataRows(path.join(runDir, f)).filter((r) => r[1] !== "" && Number.isFinite(Number(r[1])));
    if (rows.length > 0) expected.set(`/errors/${methodsByStem.get(m[1]) ?? m[1]}`, rows.length);
  }
}
const decisions = path.join(runDir, "decisions.csv");
if (fs.existsSync(decisions)) expected.set("/consensus/decisions", dataRows(decisions).length);
for (const f of fs.readdirSync(runDir)) {
  const m = f.match(/^consistency(?:_(.+))?\.csv$/);
  if (!m) continue;
  const stamps = new Set(dataRows(path.join(runDir, f)).map((r) => r[0]));
  if (stamps.size > 0) expected.set(`/consensus/consistency/ file ${f}`, stamps.size);
}
const labels = path.join(runDir, "labels.csv");
if (fs.existsSync(labels) && dataRows(labels).length > 0) expected.set("/labels", dataRows(labels).length);
atMost.set("/events", 1000);
const closedLoop = path.join(runDir, "closed_loop");
if (fs.existsSync(closedLoop)) {
  for (const stem of fs.readdirSync(closedLoop)) {
    const gtFile = path.join(closedLoop, stem, "groundtruth.csv");
    if (!fs.existsSync(gtFile)) continue;
    expected.set(`/closed_loop/${stem}/groundtruth`, dataRows(gtFile).length);
    const events = path.join(closedLoop, stem, "events.csv");
    if (fs.existsSync(events) && dataRows(events).length > 0) {
      expected.set(`/closed_loop/${stem}/events`, dataRows(events).length);
    }
  }
}

// Consistency topics are named by method (consistency_<stem>.csv holds the method's safe
// file name): match them by count per file instead of by name.
const consistencyTopics = [...counts.keys()].filter((t) => t.startsWith("/consensus/consistency/"));
const consistencyExpected = [...expected.keys()].filter((t) => t.startsWith("/consensus/consistency/"));
const consistencyCounts = consistencyExpected.map((t) => expected.get(t)).sort((a, b) => a - b);
for (const t of consistencyExpected) expected.delete(t);
const consistencyGot = consistencyTopics.map((t) => counts.get(t)).sort((a, b) => a - b);
if (JSON.stringify(consistencyGot) !== JSON.stringify(consistencyCounts)) {
  fail(`consistency topics hold [${consistencyGot}] messages, the files imply [${consistencyCounts}]`);
}

for (const [topic, n] of expected) {
  const got = counts.get(topic) ?? 0;
  if (got !== n) fail(`${topic}: ${got} messages, the run directory implies ${n}`);
}
for (const [topic, n] of atMost) {
  const got = counts.get(topic) ?? 0;
  if (got > n) fail(`${topic}: ${got} messages, at most ${n} possible`);
}
for (const topic of counts.keys()) {
  if (!expected.has(topic) && !atMost.has(topic) && !consistencyTopics.includes(topic)) {
    fail(`${topic}: a channel the run directory does not imply`);
  }
}
for (const topic of atMost.keys()) {
  if (topic !== "/events" && !counts.has(topic) && (expected.get(topic.replace(/\/world$/, "")) ?? 0) > 0) {
    fail(`${topic}: no message although its stream has rows`);
  }
}

// ---- 4. statistics ----
const stats = indexed.statistics;
if (!stats) {
  fail("no Statistics record");
} else {
  if (Number(stats.messageCount) !== indexedMessages.length) {
    fail(`Statistics: ${stats.messageCount} messages, ${indexedMessages.length} read`);
  }
  if (stats.channelCount !== indexed.channelsById.size) fail("Statistics: channel count differs");
}
if (indexed.chunkIndexes.length === 0) fail("no chunk index");

// ---- 5. the layout's topics ----
if (layoutPath) {
  const layout = JSON.parse(fs.readFileSync(layoutPath, "utf8"));
  const named = new Set();
  for (const config of Object.values(layout.configById ?? {})) {
    for (const topic of Object.keys(config.topics ?? {})) named.add(topic);
    for (const p of config.paths ?? []) named.add(p.value.split(".")[0]);
    if (config.topicPath) named.add(config.topicPath.split(".")[0]);
    if (config.topicToRender) named.add(config.topicToRender);
  }
  if (named.size === 0) fail(`${layoutPath}: names no topic`);
  for (const topic of named) {
    if (!counts.has(topic)) fail(`${layoutPath}: names ${topic}, which the file does not have`);
  }
}

if (failures.length > 0) {
  console.error(`check_mcap: ${mcapPath}: ${failures.length} problem(s):`);
  for (const f of failures) console.error(`  ${f}`);
  process.exit(1);
}
console.log(
  `check_mcap: ${mcapPath}: ${indexedMessages.length} messages on ${counts.size} channels, ` +
    `${indexed.chunkIndexes.length} chunks; all valid (${validatedOfficial} against @foxglove/schemas); ` +
    `counts match ${runDir}`,
);
