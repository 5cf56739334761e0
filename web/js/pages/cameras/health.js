// A camera's health as its source reports it: a badge for the tables, the facts and the panel
// of the camera page, read again while the page is shown.

import { api, poll } from "../../api.js";
import { clockTime, facts, fmt, h, mount, panel } from "../../ui.js";

const HEALTH_MS = 2000; // the camera's health is read again this often

/** A camera's health as a badge: online (green), stalled (amber), offline (red once seen,
 * grey when it never reported). */
export function healthBadge(health, testid) {
  const st = health?.status || "offline";
  const kind = st === "online" ? "ok" : st === "stalled" ? "warn" : health?.since ? "bad" : "idle";
  return h("span", { class: `badge ${kind}`, testid }, st);
}

function ago(t) {
  if (t === null || t === undefined) return "";
  const s = Math.max(0, Date.now() / 1000 - t);
  if (s < 90) return `${s.toFixed(s < 10 ? 1 : 0)} s ago`;
  if (s < 5400) return `${(s / 60).toFixed(0)} min ago`;
  return `${(s / 3600).toFixed(1)} h ago`;
}

/** The camera's health facts: status since when, frame rate, stalls, reconnects, drops and the
 * clock offset its source reports (a camera node's heartbeat; the twin's loop for its own). */
function healthFacts(health) {
  const hl = health || { status: "offline" };
  const row = (label, testid, value) => [
    label,
    value,
    { class: "num", testid: `camera-health-${testid}` },
  ];
  const count = (v) => (v === null || v === undefined ? "–" : String(v));
  return facts({ testid: "camera-health" }, [
    ["Status", healthBadge(hl, "camera-health-status")],
    row(
      "Since",
      "since",
      hl.since ? `${clockTime(hl.since)} (${ago(hl.since)})` : "never reported",
    ),
    row(
      "Frame rate",
      "fps",
      hl.fps === null || hl.fps === undefined ? "–" : `${fmt(hl.fps, 1)} /s`,
    ),
    row("Stalls", "stalls", count(hl.stalls)),
    row("Reconnects", "reconnects", count(hl.reconnects)),
    row("Dropped frames", "dropped", count(hl.dropped)),
    row("Dropped detections", "dropped-detections", count(hl.dropped_detections)),
    row(
      "Clock offset",
      "clock-offset",
      hl.clock_offset_s === null || hl.clock_offset_s === undefined
        ? "–"
        : `${fmt(hl.clock_offset_s * 1000, 1)} ms`,
    ),
    row("Newest frame", "last-frame", hl.last_frame_t ? ago(hl.last_frame_t) : "–"),
  ]);
}

/** The camera's health, read again every HEALTH_MS. Returns {panel, stop}. */
export function healthView(id, initial) {
  const box = h("div", null, healthFacts(initial));
  // On a failure the last health stays shown; the next read says more.
  const reads = poll(() => api(`/cameras/${id}`), {
    interval: HEALTH_MS,
    delay: true,
    onValue: (cam) => mount(box, healthFacts(cam.health)),
  });
  return {
    panel: panel(
      "Health",
      "From its source every second: a camera node's heartbeat, or the digital twin for its " +
        "own cameras. Offline: no report for 5 s; stalled: reports but no frame.",
      box,
    ),
    stop: () => reads.stop(),
  };
}
