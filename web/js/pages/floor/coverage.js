// The Floor page's coverage heat map: the Cramer-Rao bound of a floor point (or the number of
// cameras seeing it) painted under the plan, its legend, its note and the read-out under the
// mouse.

import { channels, cssVar } from "../../colours.js";
import { eventToWorld } from "../../plan.js";
import { fmt, h, mount, s } from "../../ui.js";

// Viridis (matplotlib), dark to bright, and the colours of 1, 2, 3 and 4+ cameras: tokens of
// tokens.css. The accuracy map runs bright (precise) to dark.
const VIRIDIS = Array.from({ length: 10 }, (_, i) => `viridis-${i}`);
const COUNT_COLOURS = [null, "coverage-1", "coverage-2", "coverage-3", "coverage-4"];
const NOT_SEEN_ALPHA = 70; // no camera sees the cell: the muted grey, faint

/** Return the colour (r, g, b) of t in [0, 1] on viridis (`scale`: its stops as [r, g, b]). */
function viridis(t, scale) {
  const x = Math.min(Math.max(t, 0), 1) * (scale.length - 1);
  const i = Math.min(Math.floor(x), scale.length - 2);
  const f = x - i;
  return scale[i].map((c, k) => Math.round(c + f * (scale[i + 1][k] - c)));
}

/** Paint the coverage grid as an image: one pixel per cell, row 0 at the largest y. */
function coverageImage(cov, mode, stdTop) {
  const nx = cov.x.length;
  const ny = cov.y.length;
  const canvas = document.createElement("canvas");
  canvas.width = nx;
  canvas.height = ny;
  const ctx = canvas.getContext("2d");
  const img = ctx.createImageData(nx, ny);
  const scale = VIRIDIS.map(channels);
  const counts = COUNT_COLOURS.map((name) => (name ? channels(name) : null));
  const notSeen = [...channels("muted"), NOT_SEEN_ALPHA];
  for (let iy = 0; iy < ny; iy++) {
    const row = ny - 1 - iy;
    for (let ix = 0; ix < nx; ix++) {
      const n = cov.n_cameras[iy][ix];
      const std = cov.crb_std[iy][ix];
      let c = null;
      if (mode === "count") c = counts[Math.min(n, 4)];
      else if (n > 0 && std !== null && Number.isFinite(std)) c = viridis(1 - std / stdTop, scale);
      img.data.set(c ? [c[0], c[1], c[2], 255] : notSeen, 4 * (row * nx + ix));
    }
  }
  ctx.putImageData(img, 0, 0);
  return canvas.toDataURL("image/png");
}

/** A round upper end of the accuracy colour scale (mm): the 95th percentile of the map. */
function stdScaleTop(cov) {
  const vals = cov.crb_std.flat().filter((v) => v !== null && Number.isFinite(v) && v > 0);
  if (!vals.length) return 0.01;
  vals.sort((a, b) => a - b);
  const p95 = vals[Math.floor(0.95 * (vals.length - 1))] * 1000;
  const mag = 10 ** Math.floor(Math.log10(p95));
  return ([1, 2, 2.5, 5, 10].map((m) => m * mag).find((m) => m >= p95) || 10 * mag) / 1000;
}

function legendBar(top) {
  // Bright (precise) on the left: viridis from its bright end.
  const stops = [...VIRIDIS]
    .reverse()
    .map((name, i) => `${cssVar(name)} ${((100 * i) / (VIRIDIS.length - 1)).toFixed(1)}%`)
    .join(", ");
  const ticks = [0, 0.25, 0.5, 0.75, 1].map((f) => top * 1000 * f);
  return h(
    "div",
    { class: "heat-legend", testid: "coverage-legend-std" },
    h("div", { class: "heat-legend-title" }, "Localisation accuracy: CRB σ (mm)"),
    h("div", { class: "heat-bar", style: { background: `linear-gradient(90deg, ${stops})` } }),
    h(
      "div",
      { class: "heat-ticks" },
      ticks.map((t, i) => h("span", null, i === ticks.length - 1 ? `≥ ${fmt(t, 1)}` : fmt(t, 1))),
    ),
  );
}

function countLegend() {
  const names = ["none", "1", "2", "3", "4+"];
  return h(
    "div",
    { class: "heat-legend", testid: "coverage-legend-count" },
    h("div", { class: "heat-legend-title" }, "Cameras seeing the floor (n_cameras)"),
    h(
      "div",
      { class: "legend" },
      names.map((n, i) =>
        h(
          "span",
          {
            style: {
              "--swatch": cssVar(COUNT_COLOURS[i] || "line-2"),
            },
          },
          n,
        ),
      ),
    ),
  );
}

/** The note under the map: what it shows and how much of the plan is seen, and which cameras
 * it left out (with the reason). */
function coverageNote(cov, cameras) {
  const note = h("div", { class: "small muted" });
  const cells = cov.n_cameras.flat();
  const f1 = cells.filter((n) => n >= 1).length / cells.length;
  const f2 = cells.filter((n) => n >= 2).length / cells.length;
  note.textContent =
    `Cramér–Rao bound of a floor point at pixel noise ${fmt(cov.pixel_sigma, 2)} px` +
    ` (${cov.x.length} × ${cov.y.length} cells): ${fmt(100 * f1, 0)} % of the plan seen,` +
    ` ${fmt(100 * f2, 0)} % by two or more cameras.`;
  // Cameras the map could not use are named with their reason; the rest of the space is served.
  const refused = cov.cameras_refused ? Object.entries(cov.cameras_refused) : [];
  if (refused.length) {
    const byId = new Map(cameras.map((c) => [String(c.id), c.name]));
    note.prepend(
      h(
        "div",
        { class: "small", testid: "coverage-refused" },
        "Left out of the map: " +
          refused.map(([id, why]) => `${byId.get(id) || `camera ${id}`} (${why})`).join("; "),
      ),
    );
  }
  return note;
}

/** Show, in `readout`, the world point under the mouse on `svg` and the map's cell there. */
function followMouse(svg, tf, cov, readout) {
  svg.addEventListener("mousemove", (ev) => {
    const w = eventToWorld(svg, tf, ev);
    if (!w) return;
    const [wx, wy] = w;
    const dx = cov.x[1] - cov.x[0] || 0.1;
    const dy = cov.y[1] - cov.y[0] || 0.1;
    const ix = Math.round((wx - cov.x[0]) / dx);
    const iy = Math.round((wy - cov.y[0]) / dy);
    if (ix < 0 || iy < 0 || ix >= cov.x.length || iy >= cov.y.length) {
      readout.textContent = `x ${fmt(wx, 2)} m, y ${fmt(wy, 2)} m`;
      return;
    }
    const std = cov.crb_std[iy][ix];
    readout.textContent =
      `x ${fmt(wx, 2)} m, y ${fmt(wy, 2)} m · ${cov.n_cameras[iy][ix]} cameras · ` +
      (std === null ? "not seen" : `σ ${fmt(std * 1000, 2)} mm`);
  });
}

/** The two heat maps to choose from, as radio buttons calling `choose(mode)`. */
function modeButtons(initial, choose) {
  return h(
    "div",
    { class: "segmented", role: "radiogroup", "aria-label": "Heat map" },
    [
      ["std", "Accuracy (CRB σ)"],
      ["count", "Cameras (n)"],
    ].map(([value, label]) =>
      h(
        "label",
        null,
        h("input", {
          type: "radio",
          name: "heat",
          value,
          checked: value === initial,
          testid: `heat-${value}`,
          onChange: () => choose(value),
        }),
        label,
      ),
    ),
  );
}

/**
 * Draw the coverage map `cov` (GET /maps/coverage, or null with `error` why not) into `gHeat`
 * of the plan `svg` under `tf`. Returns {controls, legend, readout, note}: the elements the
 * page lays out under the plan.
 */
export function coverageLayer(cov, error, { svg, gHeat, tf, cameras }) {
  const legend = h("div");
  const readout = h("span", { class: "small muted mono", testid: "coverage-readout" }, "");
  if (!cov) {
    const note = h(
      "div",
      { class: "small muted" },
      h(
        "span",
        { testid: "coverage-missing" },
        `No coverage map: ${error ? error.message : "the service sent none"}.`,
      ),
    );
    return { controls: null, legend, readout, note };
  }
  const stdTop = stdScaleTop(cov);
  const draw = (mode) => {
    const dx = cov.x.length > 1 ? cov.x[1] - cov.x[0] : 0.1;
    const dy = cov.y.length > 1 ? cov.y[1] - cov.y[0] : 0.1;
    gHeat.replaceChildren(
      s("image", {
        href: coverageImage(cov, mode, stdTop),
        x: tf.X(cov.x[0] - dx / 2),
        y: tf.Y(cov.y.at(-1) + dy / 2),
        width: cov.x.length * dx * tf.scale,
        height: cov.y.length * dy * tf.scale,
        preserveAspectRatio: "none",
        class: "heat-image",
        testid: "coverage-image",
        "data-mode": mode,
      }),
    );
    mount(legend, mode === "std" ? legendBar(stdTop) : countLegend());
  };
  draw("std");
  followMouse(svg, tf, cov, readout);
  return { controls: modeButtons("std", draw), legend, readout, note: coverageNote(cov, cameras) };
}
