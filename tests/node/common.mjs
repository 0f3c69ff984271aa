// Shared by the Node clients: JSON Schema validation (Ajv, draft 2020-12) and the Foxglove checks of
// the derived channels (what the 3D, Map, Image and Log panels need to draw them).
import Ajv2020 from "ajv/dist/2020.js";
import { createRequire } from "node:module";

const require = createRequire(import.meta.url);
export const foxgloveSchemas = require("@foxglove/schemas/jsonschema");

// The message encodings Foxglove and Lichtblick decode (anything else: "unsupported encoding").
export const DECODABLE = new Set(["json", "protobuf", "flatbuffer", "ros1", "cdr"]);

const ajv = new Ajv2020({ strict: false, allErrors: false, validateFormats: false });
const compiled = new Map();

export function validator(schemaName, schemaText) {
  const key = schemaName + "\u0000" + schemaText;
  let v = compiled.get(key);
  if (!v) {
    const schema = JSON.parse(schemaText);
    delete schema.$id; // the same $id may come with several channels
    v = ajv.compile(schema);
    compiled.set(key, v);
  }
  return v;
}

// The committed Foxglove schema text equals what @foxglove/schemas publishes for that type.
export function sameAsFoxglove(schemaName, schemaText) {
  const name = schemaName.replace(/^foxglove\./, "");
  const ref = foxgloveSchemas[name];
  return ref !== undefined && JSON.stringify(ref) === JSON.stringify(JSON.parse(schemaText));
}

// Problems with a derived message beyond its schema (empty list: well formed).
export function formProblems(topic, schemaName, msg) {
  const p = [];
  if (schemaName === "foxglove.SceneUpdate") {
    for (const e of msg.entities) {
      if (!e.frame_id) p.push(`${topic}: entity ${e.id} has no frame_id`);
      for (const l of e.lines) if (l.points.length < 2) p.push(`${topic}: entity ${e.id} has a line of ${l.points.length} points`);
      for (const c of e.cubes) if (!(c.size.x > 0 && c.size.y > 0 && c.size.z > 0)) p.push(`${topic}: entity ${e.id} has an empty cube`);
    }
    if (topic === "/scene/road" && !msg.entities.some((e) => e.id === "road" && e.lines.length >= 3)) p.push(`${topic}: no road lines`);
  } else if (schemaName === "foxglove.LocationFix") {
    if (!(Math.abs(msg.latitude) <= 90 && Math.abs(msg.longitude) <= 180) || (msg.latitude === 0 && msg.longitude === 0)) {
      p.push(`${topic}: not a WGS84 position (${msg.latitude}, ${msg.longitude})`);
    }
  } else if (schemaName === "foxglove.CompressedImage") {
    const data = Buffer.from(msg.data, "base64");
    if (msg.format !== "jpeg" || data.length < 100 || data[0] !== 0xff || data[1] !== 0xd8) p.push(`${topic}: not a JPEG`);
  } else if (schemaName === "foxglove.FrameTransforms") {
    if (msg.transforms.length === 0) p.push(`${topic}: no transforms`);
  }
  return p;
}
