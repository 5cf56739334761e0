// Plots drawn as SVG: per-view residual bars.

import { s } from "./ui.js";

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
