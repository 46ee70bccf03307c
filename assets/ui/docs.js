// The REST API's reference page (GET /docs): reads the OpenAPI document the server
// generates from its code (/openapi.json) and shows every operation (who may call it,
// parameters, request body, answers) and every schema, with a filter. No token needed:
// the document is open; the page calls nothing else.
"use strict";

const $ = (id) => document.getElementById(id);

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v;
    else e.setAttribute(k, v);
  }
  for (const c of children) {
    if (c === null || c === undefined) continue;
    e.append(c instanceof Node ? c : String(c));
  }
  return e;
}

let doc = null;

/// The schema a `$ref` names, and that name.
function resolve(schema) {
  if (schema && schema.$ref) {
    const name = schema.$ref.split("/").pop();
    return [doc.components.schemas[name] || {}, name];
  }
  return [schema || {}, null];
}

/// A one-line type of a schema: `string`, `integer (uint32)`, `[Name]`, `Name | null`.
function typeOf(schema) {
  const [s, name] = resolve(schema);
  if (name) return name;
  if (s.allOf && s.allOf.length === 1) return typeOf(s.allOf[0]);
  if (s.anyOf || s.oneOf) {
    return (s.anyOf || s.oneOf)
      .map((x) => (x.enum && x.enum.length === 1 && x.enum[0] === null ? "null" : typeOf(x)))
      .join(" | ");
  }
  let t = s.type || "any";
  if (t === "array") t = "[" + typeOf(s.items) + "]";
  if (t === "object" && s.additionalProperties && typeof s.additionalProperties === "object") {
    t = "{string: " + typeOf(s.additionalProperties) + "}";
  }
  if (s.format && s.format !== "double") t += " (" + s.format + ")";
  if (s.enum) t = s.enum.map((v) => JSON.stringify(v)).join(" | ");
  if (s.nullable) t += " | null";
  return t;
}

/// The members of an object schema (through one `allOf` or reference), or null.
function members(schema) {
  let [s] = resolve(schema);
  if (s.allOf && s.allOf.length === 1) [s] = resolve(s.allOf[0]);
  return s.properties ? s : null;
}

/// A schema as a tree: each member with its type, default and text; members whose type
/// is another schema open on click (to `depth` levels, which stops recursive types).
function schemaTree(schema, depth) {
  const box = el("div", { class: "schema" });
  const [top] = resolve(schema);
  if (top.anyOf && depth > 0) {
    box.append(el("div", {}, "one of:"));
    for (const alt of top.anyOf) {
      if (alt.enum && alt.enum[0] === null) continue;
      box.append(el("div", { class: "prop" }, el("span", { class: "type" }, typeOf(alt))), schemaTree(alt, depth - 1));
    }
    return box;
  }
  const obj = members(schema);
  if (!obj || depth <= 0) return box;
  const required = new Set(obj.required || []);
  for (const [name, prop] of Object.entries(obj.properties)) {
    const line = el(
      "span",
      { class: "prop" },
      el("span", { class: "name" }, name),
      required.has(name) ? el("span", { class: "req" }, "*") : null,
      ": ",
      el("span", { class: "type" }, typeOf(prop)),
      prop.default !== undefined ? " = " + JSON.stringify(prop.default) : "",
    );
    const text = prop.description ? el("div", { class: "desc" }, prop.description) : null;
    const [inner] = resolve(prop.allOf ? prop.allOf[0] : prop.items || prop);
    const nested = members(prop.allOf ? prop.allOf[0] : prop.items || prop) || inner.anyOf;
    if (nested && depth > 1) {
      const d = el("details", {}, el("summary", {}, line), text);
      d.addEventListener("toggle", () => {
        if (!d.open || d.dataset.filled) return;
        d.dataset.filled = "true";
        d.append(schemaTree(prop.allOf ? prop.allOf[0] : prop.items || prop, depth - 1));
      });
      box.append(d);
    } else {
      box.append(el("div", {}, line, text));
    }
  }
  return box;
}

function contentBlock(content) {
  const out = el("div");
  for (const [media, body] of Object.entries(content || {})) {
    out.append(el("div", {}, el("code", {}, media), " ", el("span", { class: "type" }, typeOf(body.schema))));
    out.append(schemaTree(body.schema, 6));
  }
  return out;
}

function operation(method, path, op) {
  const role = op["x-vamos-role"] || "open";
  const details = el(
    "details",
    { class: "op", id: `${method}-${path}` },
    el(
      "summary",
      {},
      el("span", { class: `method ${method}` }, method.toUpperCase()),
      el("span", { class: "path" }, path),
      el("span", {}, op.summary),
      el("span", { class: "pill role" }, role),
    ),
  );
  const body = el("div", { class: "body" });
  if (op.description) body.append(el("p", { class: "desc" }, op.description));
  if (op.parameters && op.parameters.length) {
    const rows = op.parameters.map((p) =>
      el("tr", {}, el("td", {}, el("code", {}, p.name)), el("td", {}, p.in), el("td", {}, p.required ? "required" : ""),
        el("td", { class: "type" }, typeOf(p.schema)), el("td", { class: "desc" }, p.description || "")));
    body.append(el("h3", {}, "Parameters"), el("table", {}, el("tbody", {}, ...rows)));
  }
  if (op.requestBody) {
    body.append(el("h3", {}, "Body" + (op.requestBody.required ? "" : " (optional)")));
    if (op.requestBody.description) body.append(el("div", { class: "desc" }, op.requestBody.description));
    body.append(contentBlock(op.requestBody.content));
  }
  body.append(el("h3", {}, "Answers"));
  for (const [status, answer] of Object.entries(op.responses)) {
    const [r] = answer.$ref ? [doc.components.responses[answer.$ref.split("/").pop()]] : [answer];
    body.append(el("div", {}, el("b", {}, status), " ", r.description || ""));
    if (status.startsWith("2")) body.append(contentBlock(r.content));
  }
  details.append(body);
  details.dataset.search = [method, path, op.summary, op.description || "", JSON.stringify(op)].join(" ").toLowerCase();
  return details;
}

function render() {
  $("version").textContent = `${doc.info.title} ${doc.info.version} · OpenAPI ${doc.openapi}`;
  $("intro").textContent = doc.info.description;
  const groups = new Map();
  for (const [path, item] of Object.entries(doc.paths)) {
    for (const [method, op] of Object.entries(item)) {
      const group = path.split("/")[2] ? path.split("/").slice(0, 3).join("/") : path;
      if (!groups.has(group)) groups.set(group, []);
      groups.get(group).push([method, path, op]);
    }
  }
  for (const [group, ops] of groups) {
    $("toc").append(el("h3", {}, group));
    for (const [method, path, op] of ops) {
      const node = operation(method, path, op);
      $("operations").append(node);
      const link = el("a", { href: `#${node.id}` }, `${method.toUpperCase()} ${path}`);
      link.addEventListener("click", () => { node.open = true; });
      $("toc").append(link);
    }
  }
  for (const [name, schema] of Object.entries(doc.components.schemas)) {
    const d = el("details", { class: "op", id: `schema-${name}` },
      el("summary", {}, el("span", { class: "path" }, name), el("span", { class: "desc" }, (schema.description || "").split("\n")[0])));
    d.append(el("div", { class: "body" }, schemaTree({ $ref: `#/components/schemas/${name}` }, 4)));
    d.dataset.search = (name + " " + JSON.stringify(schema)).toLowerCase();
    $("schemas").append(d);
  }
  $("filter").addEventListener("input", () => {
    const q = $("filter").value.trim().toLowerCase();
    for (const node of document.querySelectorAll("#operations > details, #schemas > details")) {
      node.classList.toggle("hidden", q !== "" && !node.dataset.search.includes(q));
    }
  });
  document.body.dataset.ready = "true";
}

fetch("/openapi.json")
  .then((r) => {
    if (!r.ok) throw new Error(`GET /openapi.json: ${r.status}`);
    return r.json();
  })
  .then((d) => { doc = d; render(); })
  .catch((e) => { $("message").textContent = String(e); });
