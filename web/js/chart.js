// Time and line plots, drawn by the vendored uPlot (web/vendor/uplot), loaded on first use.

import { colour } from "./colours.js";

let loading = null;

/** Load the vendored uPlot once; resolve to its constructor. */
export function loadUplot() {
  if (window.uPlot) return Promise.resolve(window.uPlot);
  if (!loading) {
    loading = new Promise((resolve, reject) => {
      const css = document.createElement("link");
      css.rel = "stylesheet";
      css.href = "vendor/uplot/uPlot.min.css";
      document.head.append(css);
      const script = document.createElement("script");
      script.src = "vendor/uplot/uPlot.iife.min.js";
      script.onload = () => resolve(window.uPlot);
      script.onerror = () => {
        loading = null;
        reject(new Error("the plotting library (vendor/uplot) did not load"));
      };
      document.head.append(script);
    });
  }
  return loading;
}

/** The width a chart takes in `box`: its laid-out width, between `min` and `max` pixels. */
export function chartWidth(box, { min = 320, max = 1000, fallback = 860 } = {}) {
  return Math.max(min, Math.min(box.clientWidth || fallback, max));
}

/**
 * Draw a line chart into `box` and return the uPlot: `data` is [xs, ys1, ys2, ...], `series`
 * one {label, colour (a token name of colours.js), width, dash, points (shown or not)} per y. Axes are labelled
 * `x` and `y`; `x` is not a time axis unless `time`; the y axis starts at 0 with `fromZero`.
 */
export async function lineChart(
  box,
  { title, x, y, series, data, width, height = 260, time = false, fromZero = false },
) {
  const uPlot = await loadUplot();
  return new uPlot(
    {
      title,
      width: width ?? chartWidth(box),
      height,
      // fromZero: the y axis starts at 0 and leaves a tenth above the largest value.
      scales: fromZero
        ? { x: { time }, y: { range: (_u, _min, max) => [0, (max || 1) * 1.1] } }
        : { x: { time } },
      axes: [{ label: x }, { label: y }],
      series: [
        { label: x },
        ...series.map((sr) => ({
          label: sr.label,
          stroke: colour(sr.colour),
          width: sr.width ?? 1.5,
          ...(sr.dash ? { dash: sr.dash } : {}),
          ...(sr.points === undefined
            ? {}
            : { points: { show: sr.points, fill: colour(sr.colour) } }),
        })),
      ],
    },
    data,
    box,
  );
}
