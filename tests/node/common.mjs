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

// What keeps Foxglove's and Lichtblick's JSON Schema reader (their parseJsonSchema, which builds a channel's
// fields for plots and message paths) from reading a schema: the root and every object must be
// "type": "object" with "properties"; every property one plain type (boolean, string - plain or base64 -,
// number, integer, object, or an array of one of those) or a oneOf of numeric constants.
export function foxgloveReadableProblems(schema, where = "") {
  if (schema?.type !== "object" || typeof schema.properties !== "object" || schema.properties === null) {
    return [`${where || "<root>"}: not an object with properties`];
  }
  const problems = [];
  for (const [name, field] of Object.entries(schema.properties)) {
    const here = where ? `${where}.${name}` : name;
    if (Array.isArray(field.oneOf)) {
      if (!field.oneOf.every((a) => typeof a.const === "number")) problems.push(`${here}: oneOf of non-numbers`);
      continue;
    }
    switch (field.type) {
      case "boolean": case "number": case "integer":
        break;
      case "string":
        if (field.contentEncoding !== undefined && field.contentEncoding !== "base64") problems.push(`${here}: contentEncoding`);
        break;
      case "object":
        problems.push(...foxgloveReadableProblems(field, here));
        break;
      case "array": {
        const item = field.items ?? {};
        if (item.type === "object") problems.push(...foxgloveReadableProblems(item, `${here}[]`));
        else if (!["boolean", "string", "number", "integer"].includes(item.type) || (item.type === "string" && item.contentEncoding !== undefined)) {
          problems.push(`${here}: array of ${JSON.stringify(item.type)}`);
        }
        break;
      }
      default:
        problems.push(`${here}: type ${JSON.stringify(field.type)}`);
    }
  }
  return problems;
}
