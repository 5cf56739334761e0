// The floor plan as an SVG drawing, shared by the Floor and Navigation pages: the world -> SVG
// mapping (world X right, Y up; SVG y down), poly-lines in it, the rooms with their names, and
// a click on the drawing back in world metres.

import { centroid } from "./plot.js";
import { s } from "./ui.js";

/** The mapping of a plan `width` SVG units across that holds `points` ([x, y] m) with a 0.3 m
 * margin; its height follows the plan's aspect, between `minHeight` and 760 units. `json`
 * carries the numbers a test needs to aim at a world point. */
export function planTransform(points, { width = 900, minHeight = 320 } = {}) {
  const xs = points.map((p) => p[0]);
  const ys = points.map((p) => p[1]);
  const x0 = Math.min(...xs) - 0.3;
  const x1 = Math.max(...xs) + 0.3;
  const y0 = Math.min(...ys) - 0.3;
  const y1 = Math.max(...ys) + 0.3;
  const pad = 16;
  const height = Math.round(Math.min(Math.max(((y1 - y0) / (x1 - x0)) * width, minHeight), 760));
  const scale = Math.min((width - 2 * pad) / (x1 - x0), (height - 2 * pad) / (y1 - y0));
  const ox = (width - scale * (x1 - x0)) / 2;
  const oy = (height - scale * (y1 - y0)) / 2;
  return {
    W: width,
    H: height,
    scale,
    X: (x) => ox + (x - x0) * scale,
    Y: (y) => height - oy - (y - y0) * scale,
    toWorld: (u, v) => [x0 + (u - ox) / scale, y0 + (height - oy - v) / scale],
    json: { x0, y0, ox, oy, scale, height },
  };
}

/** The `points` attribute of an SVG poly-line or polygon through world points. */
export const pointsAttr = (pts, X, Y) =>
  pts.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" ");

/** Draw each room (at least three corners) into `g`: its polygon and its name at its centroid. */
export function drawRooms(g, rooms, { X, Y }) {
  for (const room of rooms) {
    const poly = room.polygon || [];
    if (poly.length < 3) continue;
    g.append(s("polygon", { class: "room", points: pointsAttr(poly, X, Y) }));
    const [cx, cy] = centroid(poly);
    g.append(s("text", { class: "room-label", x: X(cx), y: Y(cy), "text-anchor": "middle" }, room.name));
  }
}

/** The world point (m) under a mouse event on the plan's `svg`, or null when the SVG has no
 * screen mapping (not laid out). */
export function eventToWorld(svg, tf, ev) {
  const m = svg.getScreenCTM();
  if (!m) return null;
  const p = new DOMPoint(ev.clientX, ev.clientY).matrixTransform(m.inverse());
  return tf.toWorld(p.x, p.y);
}
