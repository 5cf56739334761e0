// Plots drawn as SVG: per-view residual bars and a top-down floor plan with the cameras.

import { h, s } from "./ui.js";

/** Return about `count` round tick values covering [0, max]. */
function niceTicks(max, count = 5) {
  if (!(max > 0)) return [0, 1];
  const raw = max / count;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((m) => m >= raw) || 10 * mag;
  const ticks = [];
  for (let v = 0; v <= max + step * 0.999; v += step) ticks.push(Number(v.toPrecision(12)));
  return ticks;
}

/**
 * A bar chart of one value per item, e.g. RMS reprojection error per view (pixels),
 * with a dashed line at `reference` (the overall RMS) when given.
 */
export function barChart(values, { labels, unit = "px", title, reference, referenceLabel } = {}) {
  const W = 560;
  const H = 280;
  const m = { top: 24, right: 12, bottom: 36, left: 52 };
  const iw = W - m.left - m.right;
  const ih = H - m.top - m.bottom;
  const vmax = Math.max(...values, reference || 0, 1e-12);
  const ticks = niceTicks(vmax * 1.08);
  const top = ticks[ticks.length - 1];
  const y = (v) => m.top + ih - (v / top) * ih;
  const band = iw / values.length;
  const bw = Math.min(56, band * 0.62);
  const names = labels || values.map((_, i) => `View ${i + 1}`);

  const svg = s("svg", {
    class: "plot",
    viewBox: `0 0 ${W} ${H}`,
    role: "img",
    "aria-label": title || "bar chart",
    testid: "residual-plot",
  });
  if (title) svg.append(s("title", null, title));
  for (const t of ticks) {
    svg.append(
      s("line", { class: "grid-line", x1: m.left, x2: W - m.right, y1: y(t), y2: y(t) }),
      s("text", { x: m.left - 8, y: y(t) + 4, "text-anchor": "end" }, t.toString()),
    );
  }
  svg.append(
    s("line", { class: "axis", x1: m.left, x2: W - m.right, y1: y(0), y2: y(0) }),
    s(
      "text",
      {
        x: 14,
        y: m.top + ih / 2,
        transform: `rotate(-90 14 ${m.top + ih / 2})`,
        "text-anchor": "middle",
      },
      `RMS (${unit})`,
    ),
  );
  values.forEach((v, i) => {
    const cx = m.left + band * (i + 0.5);
    const bar = s("rect", {
      class: "bar",
      x: cx - bw / 2,
      y: y(v),
      width: bw,
      height: Math.max(0, y(0) - y(v)),
      rx: 3,
      "data-value": v,
      testid: `residual-bar-${i}`,
    });
    bar.append(s("title", null, `${names[i]}: ${v.toFixed(4)} ${unit}`));
    svg.append(
      bar,
      s("text", { class: "value", x: cx, y: y(v) - 6, "text-anchor": "middle" }, v.toFixed(3)),
      s("text", { x: cx, y: H - m.bottom + 18, "text-anchor": "middle" }, names[i]),
    );
  });
  if (reference !== undefined && reference !== null) {
    svg.append(
      s("line", { class: "mean", x1: m.left, x2: W - m.right, y1: y(reference), y2: y(reference) }),
      s(
        "text",
        { class: "mean-label", x: W - m.right, y: y(reference) - 6, "text-anchor": "end" },
        `${referenceLabel || "overall"} ${reference.toFixed(3)} ${unit}`,
      ),
    );
  }
  return svg;
}

/** The area centroid of a simple polygon [[x, y], ...] (vertex mean when it has no area). */
export function centroid(poly) {
  let a = 0;
  let cx = 0;
  let cy = 0;
  poly.forEach(([x0, y0], i) => {
    const [x1, y1] = poly[(i + 1) % poly.length];
    const cross = x0 * y1 - x1 * y0;
    a += cross;
    cx += (x0 + x1) * cross;
    cy += (y0 + y1) * cross;
  });
  if (Math.abs(a) < 1e-12) {
    return [
      poly.reduce((t, p) => t + p[0], 0) / poly.length,
      poly.reduce((t, p) => t + p[1], 0) / poly.length,
    ];
  }
  return [cx / (3 * a), cy / (3 * a)];
}

/**
 * A top-down floor plan (world X right, Y up) with rooms and, for every camera with a pose,
 * its position and the footprint direction of its optical axis.
 */
export function floorPlan(rooms, cameras) {
  const W = 640;
  const H = 360;
  const posed = cameras
    .filter((c) => Array.isArray(c.T_world_camera))
    .map((c) => {
      const T = c.T_world_camera;
      return { name: c.name, x: T[0][3], y: T[1][3], dx: T[0][2], dy: T[1][2] };
    });
  const pts = [...rooms.flatMap((r) => r.polygon || []), ...posed.map((c) => [c.x, c.y])];
  if (!pts.length) {
    return h("p", { class: "empty", testid: "floorplan-empty" }, "No rooms or posed cameras yet.");
  }
  const xs = pts.map((p) => p[0]);
  const ys = pts.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const pad = 24;
  const scale = Math.min(
    (W - 2 * pad) / Math.max(x1 - x0, 1e-6),
    (H - 2 * pad) / Math.max(y1 - y0, 1e-6),
  );
  const ox = (W - scale * (x1 - x0)) / 2;
  const oy = (H - scale * (y1 - y0)) / 2;
  const X = (x) => ox + (x - x0) * scale;
  const Y = (y) => H - oy - (y - y0) * scale; // world Y up, SVG y down
  const fills = ["#dbeafe", "#dcfce7", "#ffedd5", "#f3e8ff", "#fee2e2"];

  const svg = s("svg", {
    class: "plot floorplan",
    viewBox: `0 0 ${W} ${H}`,
    role: "img",
    "aria-label": "Floor plan with cameras",
    testid: "floorplan",
  });
  rooms.forEach((room, i) => {
    const poly = room.polygon || [];
    if (poly.length < 3) return;
    svg.append(
      s("polygon", {
        class: "room",
        points: poly.map((p) => `${X(p[0])},${Y(p[1])}`).join(" "),
        fill: fills[i % fills.length],
      }),
    );
    const [cx, cy] = centroid(poly);
    svg.append(
      s(
        "text",
        { class: "room-label", x: X(cx), y: Y(cy) + 4, "text-anchor": "middle" },
        room.name,
      ),
    );
  });
  // A scale bar of a round length, bottom left.
  const metres = [0.5, 1, 2, 5, 10].find((v) => v * scale >= 50) || 10;
  const bx = 12;
  const by = H - 10;
  svg.append(
    s("line", {
      x1: bx,
      x2: bx + metres * scale,
      y1: by,
      y2: by,
      stroke: "#475569",
      "stroke-width": 2,
    }),
    s("line", { x1: bx, x2: bx, y1: by - 4, y2: by + 1, stroke: "#475569", "stroke-width": 2 }),
    s("line", {
      x1: bx + metres * scale,
      x2: bx + metres * scale,
      y1: by - 4,
      y2: by + 1,
      stroke: "#475569",
      "stroke-width": 2,
    }),
    s("text", { x: bx + (metres * scale) / 2, y: by - 6, "text-anchor": "middle" }, `${metres} m`),
  );
  for (const c of posed) {
    const len = Math.hypot(c.dx, c.dy);
    const reach = 40;
    if (len > 1e-3) {
      // The optical axis's horizontal component: where the camera looks on the floor.
      const ux = c.dx / len;
      const uy = -c.dy / len;
      const [px, py] = [X(c.x), Y(c.y)];
      const spread = 0.45;
      const a = [
        px + reach * (ux * Math.cos(spread) - uy * Math.sin(spread)),
        py + reach * (ux * Math.sin(spread) + uy * Math.cos(spread)),
      ];
      const b = [
        px + reach * (ux * Math.cos(-spread) - uy * Math.sin(-spread)),
        py + reach * (ux * Math.sin(-spread) + uy * Math.cos(-spread)),
      ];
      svg.append(
        s("polygon", { class: "cam-view", points: `${px},${py} ${a.join(",")} ${b.join(",")}` }),
      );
    } else {
      svg.append(s("circle", { class: "cam-view", cx: X(c.x), cy: Y(c.y), r: 16 }));
    }
    const right = X(c.x) > W * 0.7; // keep labels near the right edge inside the drawing
    svg.append(
      s("circle", { class: "cam", cx: X(c.x), cy: Y(c.y), r: 5 }, s("title", null, c.name)),
      s(
        "text",
        {
          class: "cam-label",
          x: X(c.x) + (right ? -9 : 9),
          y: Y(c.y) - 8,
          "text-anchor": right ? "end" : "start",
        },
        c.name,
      ),
    );
  }
  return svg;
}
