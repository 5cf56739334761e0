// Small DOM helpers shared by the pages: element builder, errors, toasts, number formatting.

const SVG_NS = "http://www.w3.org/2000/svg";

function append(el, children) {
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
}

function applyAttrs(el, attrs) {
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key.startsWith("on") && typeof value === "function") {
      el.addEventListener(key.slice(2).toLowerCase(), value);
    } else if (key === "class") {
      el.setAttribute("class", value);
    } else if (key === "style" && typeof value === "object") {
      for (const [prop, v] of Object.entries(value)) {
        if (prop.startsWith("--")) el.style.setProperty(prop, v);
        else el.style[prop] = v;
      }
    } else if (key === "testid") {
      el.setAttribute("data-testid", value);
    } else if (key in el && typeof value !== "string" && !(el instanceof SVGElement)) {
      el[key] = value;
    } else {
      el.setAttribute(key, value === true ? "" : String(value));
    }
  }
}

/** Create an HTML element: h("a", {href, class, testid, onClick}, ...children). */
export function h(tag, attrs, ...children) {
  const el = document.createElement(tag);
  applyAttrs(el, attrs);
  append(el, children);
  return el;
}

/** Create an SVG element, same call shape as h(). */
export function s(tag, attrs, ...children) {
  const el = document.createElementNS(SVG_NS, tag);
  applyAttrs(el, attrs);
  append(el, children);
  return el;
}

/** An alert box for an error: the problem-details title, detail and per-field reasons. */
export function errorBox(err, testid = "error") {
  const fields = (err.errors || []).map((e) =>
    h("li", null, e.field ? h("code", null, e.field) : null, e.field ? ": " : "", e.reason || ""),
  );
  return h(
    "div",
    { class: "alert", role: "alert", testid },
    h("strong", null, err.title || "Something went wrong"),
    err.detail || (err.title ? "" : err.message),
    fields.length ? h("ul", null, fields) : null,
    err.status === 401
      ? h(
          "p",
          { class: "small" },
          "Sign in at the top right with the access token that ",
          h("code", null, "intspace serve"),
          " printed on its first start.",
        )
      : null,
  );
}

export function infoBox(text, testid) {
  return h("div", { class: "alert info", role: "note", testid }, text);
}

/** Show a short message in the corner; errors stay longer. */
export function toast(message, kind = "ok") {
  const el = h("div", { class: `toast ${kind}`, testid: `toast-${kind}` }, message);
  document.getElementById("toasts").append(el);
  setTimeout(() => el.remove(), kind === "error" ? 9000 : 4500);
}

export function toastError(err) {
  const detail = err.detail ? `: ${err.detail}` : "";
  toast(err.title ? `${err.title}${detail}` : err.message, "error");
}

export function badge(text, kind) {
  return h("span", { class: `badge ${kind || text}` }, text);
}

export function statusBadge(status, testid) {
  const busy = status === "queued" || status === "running";
  return h(
    "span",
    { class: `badge ${status}`, testid },
    busy ? h("span", { class: "spinner", "aria-hidden": "true" }) : null,
    status,
  );
}

export function panel(title, subtitle, ...children) {
  const head = title || subtitle ? panelHead(title, subtitle) : null;
  return h("section", { class: "panel" }, head, ...children);
}

/** A panel's head: its title (text, or a heading element of its own) over its subtitle, and
 * `actions` (buttons, badges) beside them. */
export function panelHead(title, subtitle, ...actions) {
  return h(
    "div",
    { class: "panel-head" },
    h(
      "div",
      null,
      title instanceof Node ? title : title ? h("h2", null, title) : null,
      subtitle ? h("p", null, subtitle) : null,
    ),
    ...actions,
  );
}

/** A Unix time (s) as the local clock's time of day, or an en dash when missing. */
export function clockTime(t) {
  return t === null || t === undefined
    ? "–"
    : new Date(t * 1000).toLocaleTimeString([], { hour12: false });
}

/** A number with fixed decimals, or an en dash when missing. */
export function fmt(x, digits = 2) {
  if (x === null || x === undefined || Number.isNaN(Number(x))) return "–";
  return Number(x).toFixed(digits);
}

/** A number with a given count of significant digits (distortion coefficients, small errors). */
export function sig(x, digits = 4) {
  if (x === null || x === undefined || Number.isNaN(Number(x))) return "–";
  const v = Number(x);
  if (v === 0) return "0";
  return Math.abs(v) >= 1e5 || Math.abs(v) < 1e-4
    ? v.toExponential(digits - 1)
    : v.toPrecision(digits);
}

export function when(iso) {
  if (!iso) return "–";
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  return d.toLocaleString(undefined, {
    year: "numeric",
    month: "short",
    day: "numeric",
    hour: "2-digit",
    minute: "2-digit",
    second: "2-digit",
  });
}

export function duration(startIso, endIso) {
  if (!startIso || !endIso) return "–";
  const ms = new Date(endIso) - new Date(startIso);
  if (!Number.isFinite(ms)) return "–";
  return ms < 1000 ? `${ms} ms` : `${(ms / 1000).toFixed(2)} s`;
}

/** A 3x3 (or any) matrix as a bracketed table. */
export function matrixTable(M, digits = 3, testid) {
  return h(
    "table",
    { class: "matrix", testid, "aria-label": "matrix" },
    h(
      "tbody",
      null,
      M.map((row) =>
        h(
          "tr",
          null,
          row.map((v) => h("td", null, fmt(v, digits))),
        ),
      ),
    ),
  );
}

/** A table: a header row of `columns` (each a name, or [name, the th's attributes]) above
 * `rows` (tr elements). */
export function table(attrs, columns, rows) {
  const th = (c) => (Array.isArray(c) ? h("th", c[1], c[0]) : h("th", null, c));
  return h(
    "table",
    attrs,
    h("thead", null, h("tr", null, columns.map(th))),
    h("tbody", null, rows),
  );
}

/** A list of facts (dl.facts) with `attrs`: one [label, value, the value's attributes] a row
 * (null rows left out). */
export function facts(attrs, rows) {
  const fact = ([label, value, valueAttrs]) => [h("dt", null, label), h("dd", valueAttrs, value)];
  return h("dl", { class: "facts", ...attrs }, rows.filter(Boolean).map(fact));
}

/** A table row (tr) that opens `href` when clicked anywhere but on its own links. */
export function linkRow(href, attrs, ...cells) {
  const open = (ev) => {
    if (ev.target.tagName !== "A") location.hash = href;
  };
  return h("tr", { class: "link-row", ...attrs, onClick: open }, ...cells);
}

/** A table of results, one row per [label, value, testid?] (null rows left out); the values
 * in monospace. */
export function resultsTable(testid, rows) {
  return h(
    "table",
    { class: "nav-metrics", testid },
    h(
      "tbody",
      null,
      rows
        .filter(Boolean)
        .map(([label, value, id]) =>
          h("tr", null, h("th", null, label), h("td", { class: "mono", testid: id }, value)),
        ),
    ),
  );
}

/** Replace a container's children. */
export function mount(container, ...children) {
  container.replaceChildren();
  append(container, children);
}
