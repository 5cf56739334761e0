// The Floor page's live positions: every live target of the space on the plan (marker, 2-sigma
// ellipse, track) and in a table, from the WebSocket stream (GET /targets polled when it is
// unavailable), with the ended targets of the last ten minutes on request.

import { api, inSpace, poll } from "../../api.js";
import { drawTargets, drawTracks, ellipse2Sigma, targetKind } from "../../plan.js";
import { fmt, h, toastError } from "../../ui.js";

const POLL_MS = 500; // GET /targets when the WebSocket stream is unavailable
const STREAM_WAIT_MS = 3000; // the stream has this long to open before polling takes over
const TRACK_POINTS = 400; // newest points kept per target in the page
const MIN_ELLIPSE_PX = 16; // ellipses smaller than this are scaled up (and the scale noted)
const SCALES = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];

/** Return the targets of whatever shape GET /targets answers. */
export function targetsOf(body) {
  return Array.isArray(body) ? body : body?.items || body?.targets || [];
}

/** Return, per kind, a round factor that makes the kind's largest ellipse visible at `scale`
 * (SVG units per metre): the robot's marker is located far better than a person's feet. */
function ellipseScales(items, scale) {
  const factors = new Map();
  for (const kind of ["robot", "person", "unknown"]) {
    const ofKind = items.filter((t) => t.cov && targetKind(t) === kind);
    if (!ofKind.length) continue;
    const largest = Math.max(...ofKind.map((t) => ellipse2Sigma(t.cov).a));
    const needed = largest > 0 ? MIN_ELLIPSE_PX / (largest * scale) : 1;
    factors.set(kind, SCALES.find((f) => f >= needed) || SCALES.at(-1));
  }
  return factors;
}

/** The note saying how much each kind's ellipses are enlarged. */
function scaleText(factors) {
  if (!factors.size) return "";
  const notes = [...factors].map(([kind, k]) => `${kind} ${k > 1 ? `×${k}` : "true size"}`);
  const enlarged = [...factors.values()].some((k) => k > 1);
  return (
    `2σ ellipses: ${notes.join(", ")}` + (enlarged ? " (enlarged where tiny at this scale)" : "")
  );
}

/** One table row per target: label, kind, state, position and one standard deviation. */
function targetRow(t) {
  const e = t.cov ? ellipse2Sigma(t.cov) : null;
  return h(
    "tr",
    { testid: `target-row-${t.label}` },
    h("td", null, t.label),
    h("td", null, t.kind),
    h("td", null, t.state || "–"),
    h("td", { class: "num" }, fmt(t.xy[0], 3)),
    h("td", { class: "num" }, fmt(t.xy[1], 3)),
    h("td", { class: "num" }, e ? fmt((e.a / 2) * 1000, 1) : "–"),
  );
}

/** The time of day of a capture time (Unix seconds on the service's clock), to a tenth. */
function seenAt(when) {
  if (!(Number.isFinite(when) && when > 0)) return "";
  const tenth = String(Math.floor((when % 1) * 10));
  return `seen at ${new Date(when * 1000).toLocaleTimeString([], { hour12: false })}.${tenth}`;
}

/** The live targets, their tracks and what they are drawn into. */
class LiveTargets {
  constructor(tf, groups) {
    this.tf = tf;
    this.groups = groups; // {tracks, ellipses, targets}: SVG groups of the plan
    this.tracks = new Map(); // label -> [[x, y], ...]
    this.latest = new Map(); // label -> target
    this.scaleNote = h("span", { class: "small muted", testid: "ellipse-scale" }, "");
    this.clock = h("span", { class: "mono small", testid: "positions-time" }, "");
    this.emptyNote = h(
      "p",
      { class: "small muted", testid: "targets-empty" },
      "No target located yet.",
    );
    this.tableBody = h("tbody");
  }

  draw() {
    const items = [...this.latest.values()].filter((t) => Array.isArray(t.xy));
    this.emptyNote.hidden = items.length > 0;
    const factors = ellipseScales(items, this.tf.scale);
    this.scaleNote.textContent = scaleText(factors);
    const tracks = [...this.tracks].map(([label, points]) => ({
      label,
      points,
      kind: this.latest.get(label)?.kind || "unknown",
      testid: `track-${label}`,
    }));
    drawTracks(this.groups.tracks, tracks, this.tf);
    drawTargets(
      this.groups.ellipses,
      this.groups.targets,
      items,
      this.tf,
      (k) => factors.get(k) || 1,
    );
    this.tableBody.replaceChildren(...items.map(targetRow));
  }

  /** Take `items`, the whole live set (the stream and GET /targets send every live target):
   * a target missing from it has ended and leaves the plan with its track. `t`: when. */
  accept(items, t) {
    for (const label of [...this.latest.keys()]) {
      if (!items.some((x) => x.label === label)) {
        this.latest.delete(label);
        this.tracks.delete(label);
      }
    }
    for (const target of items) {
      if (!target.label || !Array.isArray(target.xy)) continue;
      this.latest.set(target.label, { ...this.latest.get(target.label), ...target });
      const pts = this.tracks.get(target.label) || [];
      const last = pts.at(-1);
      if (!last || last[0] !== target.xy[0] || last[1] !== target.xy[1]) {
        pts.push(target.xy);
        if (pts.length > TRACK_POINTS) pts.splice(0, pts.length - TRACK_POINTS);
      }
      this.tracks.set(target.label, pts);
    }
    const when = t ?? Math.max(0, ...items.map((x) => x.t || 0));
    this.clock.textContent = seenAt(when);
    this.clock.dataset.t = Number.isFinite(when) ? String(when) : "";
    this.draw();
  }

  /** Read the earlier positions of every live target in one request, so a track shows where a
   * target went before the page opened. */
  async loadRecent() {
    try {
      const recent = await api(inSpace(`/targets/tracks?points=${TRACK_POINTS}`));
      for (const tr of recent.tracks || []) {
        const pts = tr.points.map((p) => [p[1], p[2]]);
        if (pts.length) this.tracks.set(tr.label, pts);
      }
    } catch {
      /* no history yet: the live stream fills the tracks */
    }
  }

  /** Forget every track (the twin was reset). */
  clearTracks() {
    this.tracks.clear();
    this.draw();
  }
}

/** Ended targets of the last ten minutes, on request: grey dashed tracks under the live ones,
 * drawn into `g`. Returns {toggle, note}. */
function endedTracks(g, tf) {
  const toggle = h("input", { type: "checkbox", testid: "history-toggle" });
  const note = h("span", { class: "small muted", testid: "history-note" }, "");
  const draw = async () => {
    g.replaceChildren();
    note.textContent = "";
    if (!toggle.checked) return;
    const since = Date.now() / 1000 - 600;
    const body = await api(inSpace(`/targets/tracks?state=all&since=${since}&targets=200`));
    const ended = (body.tracks || []).filter((tr) => tr.state === "ended");
    note.textContent = `${ended.length} ended in the last 10 min`;
    const drawn = ended.map((tr) => ({
      label: tr.label,
      kind: tr.kind,
      ended: true,
      points: tr.points.map((p) => [p[1], p[2]]),
      testid: `history-${tr.label}`,
    }));
    drawTracks(g, drawn, tf);
  };
  toggle.addEventListener("change", () => draw().catch(toastError));
  return { toggle, note };
}

/**
 * Follow the live targets of `space`: from the WebSocket stream, or GET /targets every POLL_MS
 * when it does not open or closes; `badge` says which. `onTargets(items, t)` takes each set.
 * Returns a stop function.
 */
function followTargets(space, badge, onTargets) {
  let stopped = false;
  let targetPoll = null;
  let socket = null;
  const startPolling = () => {
    if (stopped || targetPoll !== null) return;
    badge.textContent = `polling every ${POLL_MS / 1000} s`;
    badge.className = "badge warn";
    badge.dataset.source = "polling";
    targetPoll = poll(() => api(inSpace("/targets")), {
      interval: POLL_MS,
      onValue: (body) => onTargets(targetsOf(body)),
      onError: (err) => {
        badge.textContent = `positions unavailable (${err.status || "offline"})`;
        badge.className = "badge bad";
      },
    });
  };
  try {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    // The session cookie authenticates the stream (the service checks the page's Origin).
    const only = space ? `?space_id=${space.id}` : "";
    socket = new WebSocket(`${proto}://${location.host}/api/v1/ws/targets${only}`, ["intspace"]);
    const fallback = setTimeout(() => {
      if (socket.readyState !== WebSocket.OPEN) {
        socket.close();
        startPolling();
      }
    }, STREAM_WAIT_MS);
    socket.addEventListener("open", () => {
      clearTimeout(fallback);
      badge.textContent = "live (WebSocket)";
      badge.className = "badge ok";
      badge.dataset.source = "websocket";
    });
    socket.addEventListener("message", (ev) => {
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch {
        return;
      }
      if (msg.type === "positions" && Array.isArray(msg.targets)) onTargets(msg.targets, msg.t);
    });
    socket.addEventListener("close", () => {
      clearTimeout(fallback);
      if (!stopped) startPolling();
    });
  } catch {
    startPolling();
  }
  return () => {
    stopped = true;
    targetPoll?.stop();
    if (socket) socket.close();
  };
}

/** The targets table (one row per live target), under its empty note. */
function targetsTable(live) {
  const heads = ["Target", "Kind", "State", "x (m)", "y (m)", "sd (mm)"];
  return [
    live.emptyNote,
    h(
      "div",
      { class: "table-wrap" },
      h(
        "table",
        { testid: "targets-table", class: "compact" },
        h(
          "thead",
          null,
          h(
            "tr",
            null,
            heads.map((t, i) => h("th", { class: i >= 3 ? "num" : null }, t)),
          ),
        ),
        live.tableBody,
      ),
    ),
  ];
}

/**
 * Show the live targets of `space` on the plan (`tf`, its groups {history, tracks, ellipses,
 * targets}), starting from `initial` (GET /targets). Returns the elements the page lays out
 * ({badge, clock, scaleNote, history: {toggle, note}, table}), clearTracks() and stop().
 */
export async function liveTargets(space, tf, groups, initial) {
  const live = new LiveTargets(tf, groups);
  await live.loadRecent();
  live.accept(initial);
  const badge = h("span", { class: "badge", testid: "positions-source" }, "connecting…");
  const stop = followTargets(space, badge, (items, t) => live.accept(items, t));
  return {
    badge,
    clock: live.clock,
    scaleNote: live.scaleNote,
    history: endedTracks(groups.history, tf),
    table: targetsTable(live),
    clearTracks: () => live.clearTracks(),
    stop,
  };
}
