// Floor: the chosen space's plan seen from above with the coverage heat map under it, the live
// positions of its robot and people (2-sigma covariance ellipses, tracks) and, in the twin's
// home, the digital twin's controls.

import { api, currentSpace, inSpace, list, poll, spaceById } from "../api.js";
import {
  drawCameras,
  drawRooms,
  drawScaleBar,
  drawTargets as drawTargetMarks,
  drawTracks,
  drawTruth,
  drawZones,
  ellipse2Sigma,
  eventToWorld,
  planSvg,
  planTransform,
  targetKind,
} from "../plan.js";
import { fmt, h, infoBox, mount, panel, s, toastError } from "../ui.js";

const POLL_MS = 500; // GET /targets when the WebSocket stream is unavailable
const TWIN_MS = 1000;
const ZONES_MS = 1000; // GET /spaces/{id}/zones: live occupancy
const TRACK_POINTS = 400; // newest points kept per target in the page
const W = 900; // SVG user units across; the height follows the plan's aspect, at least 360
const MIN_ELLIPSE_PX = 16; // ellipses smaller than this are scaled up (and the scale noted)
const SCALES = [1, 2, 5, 10, 20, 50, 100, 200, 500, 1000];
// Viridis (matplotlib), dark to bright; the accuracy map runs bright (precise) to dark.
const VIRIDIS = [
  [68, 1, 84],
  [72, 40, 120],
  [62, 74, 137],
  [49, 104, 142],
  [38, 130, 142],
  [31, 158, 137],
  [53, 183, 121],
  [110, 206, 88],
  [181, 222, 43],
  [253, 231, 37],
];
// Cameras seeing a cell: none, 1 (position only from one view), 2, 3, 4 or more.
const COUNT_COLOURS = [null, [254, 215, 170], [147, 197, 253], [59, 130, 246], [30, 64, 175]];

/** Return the colour (r, g, b) of t in [0, 1] on viridis. */
function viridis(t) {
  const x = Math.min(Math.max(t, 0), 1) * (VIRIDIS.length - 1);
  const i = Math.min(Math.floor(x), VIRIDIS.length - 2);
  const f = x - i;
  return VIRIDIS[i].map((c, k) => Math.round(c + f * (VIRIDIS[i + 1][k] - c)));
}

function targetsOf(body) {
  return Array.isArray(body) ? body : body?.items || body?.targets || [];
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
  for (let iy = 0; iy < ny; iy++) {
    const row = ny - 1 - iy;
    for (let ix = 0; ix < nx; ix++) {
      const n = cov.n_cameras[iy][ix];
      const std = cov.crb_std[iy][ix];
      let rgb = null;
      if (mode === "count") rgb = COUNT_COLOURS[Math.min(n, 4)];
      else if (n > 0 && std !== null && Number.isFinite(std)) rgb = viridis(1 - std / stdTop);
      const o = 4 * (row * nx + ix);
      if (rgb) {
        img.data.set([rgb[0], rgb[1], rgb[2], 255], o);
      } else {
        img.data.set([100, 116, 139, 70], o); // no camera sees it: a faint grey
      }
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
    .map((c, i) => `rgb(${c.join(",")}) ${((100 * i) / (VIRIDIS.length - 1)).toFixed(1)}%`)
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
              "--swatch": COUNT_COLOURS[i] ? `rgb(${COUNT_COLOURS[i].join(",")})` : "#cbd5e1",
            },
          },
          n,
        ),
      ),
    ),
  );
}

/** Draw the zones of these spaces into `g`, read again every second; return the poll. */
function followZones(g, spaceIds, tf) {
  return poll(() => Promise.all(spaceIds.map((id) => api(`/spaces/${id}/zones`))), {
    interval: ZONES_MS,
    // On a failure the plan stays as it was; the next read tries again.
    onValue: (all) => drawZones(g, all.flat(), tf),
  });
}

async function settle(promise) {
  try {
    return { value: await promise };
  } catch (error) {
    return { error };
  }
}

export async function renderFloor(main) {
  const space = currentSpace();
  const [rooms, cameras, twin0, coverage, targets0] = await Promise.all([
    list(inSpace("/rooms"), { limit: 200 }),
    settle(list(inSpace("/cameras", { unassigned: true }), { limit: 200 })),
    settle(api("/twin")),
    settle(api(inSpace("/maps/coverage?format=json"))),
    settle(api(inSpace("/targets"))),
  ]);
  // The twin's controls and ground truth belong to its home: another space has neither.
  const twinElsewhere =
    space && twin0.value?.enabled && twin0.value.space_id && twin0.value.space_id !== space.id;
  const cams = (cameras.value?.items || []).filter((c) => Array.isArray(c.T_world_camera));
  const cov = coverage.value && Array.isArray(coverage.value.x) ? coverage.value : null;

  const extent = [
    ...rooms.items.flatMap((r) => r.polygon || []),
    ...cams.map((c) => [c.T_world_camera[0][3], c.T_world_camera[1][3]]),
  ];
  if (cov) extent.push([cov.x[0], cov.y[0]], [cov.x.at(-1), cov.y.at(-1)]);
  for (const t of targetsOf(targets0.value)) if (t.xy) extent.push(t.xy);
  if (!extent.length) extent.push([0, 0], [5, 4]);
  const tf = planTransform(extent, { width: W, minHeight: 360 });
  const { X, Y } = tf;

  // -- the drawing ---------------------------------------------------------------------------
  const svg = planSvg(tf, {
    className: "plot floormap",
    label: "Floor plan with live positions",
    testid: "floor-map",
  });
  const gHeat = s("g", { class: "heat" });
  const gRooms = s("g");
  const gZones = s("g", { class: "zones", testid: "floor-zones" });
  const gCams = s("g");
  const gHistory = s("g");
  const gTracks = s("g");
  const gTruth = s("g");
  const gEllipses = s("g");
  const gTargets = s("g");
  svg.append(gHeat, gRooms, gZones, gCams, gHistory, gTracks, gTruth, gEllipses, gTargets);

  drawRooms(gRooms, rooms.items, tf);
  const spaceIds = [...new Set(rooms.items.map((r) => r.space_id))];
  const zonePoll = followZones(gZones, spaceIds, tf);
  drawCameras(gCams, cams, tf);
  drawScaleBar(svg, tf);

  // -- coverage ------------------------------------------------------------------------------
  const heatNote = h("div", { class: "small muted" });
  const legendBox = h("div");
  const readout = h("span", { class: "small muted mono", testid: "coverage-readout" }, "");
  let heatMode = "std";
  const stdTop = cov ? stdScaleTop(cov) : 1;
  // Cameras the map could not use are named with their reason; the rest of the space is served.
  const refused = cov && cov.cameras_refused ? Object.entries(cov.cameras_refused) : [];
  if (refused.length) {
    const byId = new Map((cameras.value?.items || []).map((c) => [String(c.id), c.name]));
    heatNote.append(
      h(
        "div",
        { class: "small", testid: "coverage-refused" },
        "Left out of the map: " +
          refused.map(([id, why]) => `${byId.get(id) || `camera ${id}`} (${why})`).join("; "),
      ),
    );
  }
  const drawHeat = () => {
    gHeat.replaceChildren();
    if (!cov) return;
    const dx = cov.x.length > 1 ? cov.x[1] - cov.x[0] : 0.1;
    const dy = cov.y.length > 1 ? cov.y[1] - cov.y[0] : 0.1;
    const x0 = cov.x[0] - dx / 2;
    const y1 = cov.y.at(-1) + dy / 2;
    gHeat.append(
      s("image", {
        href: coverageImage(cov, heatMode, stdTop),
        x: X(x0),
        y: Y(y1),
        width: cov.x.length * dx * tf.scale,
        height: cov.y.length * dy * tf.scale,
        preserveAspectRatio: "none",
        class: "heat-image",
        testid: "coverage-image",
        "data-mode": heatMode,
      }),
    );
    mount(legendBox, heatMode === "std" ? legendBar(stdTop) : countLegend());
  };
  const modeButtons = h(
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
          checked: value === heatMode,
          testid: `heat-${value}`,
          onChange: () => {
            heatMode = value;
            drawHeat();
          },
        }),
        label,
      ),
    ),
  );
  if (cov) {
    const f1 = cov.n_cameras.flat().filter((n) => n >= 1).length / cov.n_cameras.flat().length;
    const f2 = cov.n_cameras.flat().filter((n) => n >= 2).length / cov.n_cameras.flat().length;
    heatNote.textContent =
      `Cramér–Rao bound of a floor point at pixel noise ${fmt(cov.pixel_sigma, 2)} px` +
      ` (${cov.x.length} × ${cov.y.length} cells): ${fmt(100 * f1, 0)} % of the plan seen,` +
      ` ${fmt(100 * f2, 0)} % by two or more cameras.`;
    drawHeat();
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
  } else {
    heatNote.append(
      h(
        "span",
        { testid: "coverage-missing" },
        `No coverage map: ${coverage.error ? coverage.error.message : "the service sent none"}.`,
      ),
    );
  }

  // -- live targets ----------------------------------------------------------------------------
  const tracks = new Map(); // label -> [[x, y], ...]
  const latest = new Map(); // label -> target
  const ellipseScale = new Map(); // kind -> factor the ellipses are drawn larger by
  const sourceBadge = h("span", { class: "badge", testid: "positions-source" }, "connecting…");
  const scaleNote = h("span", { class: "small muted", testid: "ellipse-scale" }, "");
  const clock = h("span", { class: "mono small", testid: "positions-time" }, "");
  const emptyNote = h(
    "p",
    { class: "small muted", testid: "targets-empty" },
    "No target located yet.",
  );
  const tableBody = h("tbody");

  const drawTargets = () => {
    const items = [...latest.values()].filter((t) => Array.isArray(t.xy));
    emptyNote.hidden = items.length > 0;
    // One scale per kind (the robot's marker is located far better than a person's feet): a
    // round factor that makes the kind's largest ellipse visible.
    const notes = [];
    for (const kind of ["robot", "person", "unknown"]) {
      const ofKind = items.filter((t) => t.cov && targetKind(t) === kind);
      if (!ofKind.length) continue;
      const largest = Math.max(...ofKind.map((t) => ellipse2Sigma(t.cov).a));
      const needed = largest > 0 ? MIN_ELLIPSE_PX / (largest * tf.scale) : 1;
      const k = SCALES.find((f) => f >= needed) || SCALES.at(-1);
      ellipseScale.set(kind, k);
      notes.push(`${kind} ${k > 1 ? `×${k}` : "true size"}`);
    }
    scaleNote.textContent = notes.length
      ? `2σ ellipses: ${notes.join(", ")}` +
        ([...ellipseScale.values()].some((k) => k > 1) ? " (enlarged where tiny at this scale)" : "")
      : "";
    drawTracks(
      gTracks,
      [...tracks.entries()].map(([label, points]) => ({
        label,
        points,
        kind: latest.get(label)?.kind || "unknown",
        testid: `track-${label}`,
      })),
      tf,
    );
    drawTargetMarks(gEllipses, gTargets, items, tf, (kind) => ellipseScale.get(kind) || 1);
    tableBody.replaceChildren(
      ...items.map((t) => {
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
      }),
    );
  };

  // items: the whole live set (the stream and GET /targets send every live target), so a
  // target missing from it has ended and leaves the plan with its track.
  const accept = (items, t) => {
    const seen = new Set();
    for (const label of [...latest.keys()]) {
      if (!items.some((x) => x.label === label)) {
        latest.delete(label);
        tracks.delete(label);
      }
    }
    for (const target of items) {
      if (!target.label || !Array.isArray(target.xy)) continue;
      seen.add(target.label);
      const prev = latest.get(target.label);
      latest.set(target.label, { ...prev, ...target });
      const pts = tracks.get(target.label) || [];
      const last = pts.at(-1);
      if (!last || last[0] !== target.xy[0] || last[1] !== target.xy[1]) {
        pts.push(target.xy);
        if (pts.length > TRACK_POINTS) pts.splice(0, pts.length - TRACK_POINTS);
      }
      tracks.set(target.label, pts);
    }
    const when = t ?? Math.max(0, ...items.map((x) => x.t || 0));
    // Capture times are Unix seconds on the service's clock: shown as the time of day.
    clock.textContent =
      Number.isFinite(when) && when > 0
        ? `seen at ${new Date(when * 1000).toLocaleTimeString([], { hour12: false })}.${String(
            Math.floor((when % 1) * 10),
          )}`
        : "";
    clock.dataset.t = Number.isFinite(when) ? String(when) : "";
    drawTargets();
  };

  // Earlier positions of every live target in one request, so a track shows where a target
  // went before the page opened.
  const initial = targetsOf(targets0.value);
  try {
    const recent = await api(inSpace(`/targets/tracks?points=${TRACK_POINTS}`));
    for (const tr of recent.tracks || []) {
      const pts = tr.points.map((p) => [p[1], p[2]]);
      if (pts.length) tracks.set(tr.label, pts);
    }
  } catch {
    /* no history yet: the live stream fills the tracks */
  }
  accept(initial);

  // Ended targets of the last ten minutes, on request: grey dashed tracks under the live ones.
  const historyToggle = h("input", { type: "checkbox", testid: "history-toggle" });
  const historyNote = h("span", { class: "small muted", testid: "history-note" }, "");
  const drawHistory = async () => {
    gHistory.replaceChildren();
    historyNote.textContent = "";
    if (!historyToggle.checked) return;
    const since = Date.now() / 1000 - 600;
    const body = await api(inSpace(`/targets/tracks?state=all&since=${since}&targets=200`));
    const ended = (body.tracks || []).filter((tr) => tr.state === "ended");
    historyNote.textContent = `${ended.length} ended in the last 10 min`;
    drawTracks(
      gHistory,
      ended.map((tr) => ({
        label: tr.label,
        kind: tr.kind,
        ended: true,
        points: tr.points.map((p) => [p[1], p[2]]),
        testid: `history-${tr.label}`,
      })),
      tf,
    );
  };
  historyToggle.addEventListener("change", () => drawHistory().catch(toastError));

  let stopped = false;
  let targetPoll = null;
  let socket = null;
  const startPolling = () => {
    if (stopped || targetPoll !== null) return;
    sourceBadge.textContent = `polling every ${POLL_MS / 1000} s`;
    sourceBadge.className = "badge warn";
    sourceBadge.dataset.source = "polling";
    targetPoll = poll(() => api(inSpace("/targets")), {
      interval: POLL_MS,
      onValue: (body) => accept(targetsOf(body)),
      onError: (err) => {
        sourceBadge.textContent = `positions unavailable (${err.status || "offline"})`;
        sourceBadge.className = "badge bad";
      },
    });
  };
  try {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    // The session cookie authenticates the stream (the service checks the page's Origin).
    const only = space ? `?space_id=${space.id}` : "";
    socket = new WebSocket(`${proto}://${location.host}/api/v1/ws/targets${only}`, ["intspace"]);
    const fallback = setTimeout(() => {
      if (socket && socket.readyState !== WebSocket.OPEN) {
        socket.close();
        startPolling();
      }
    }, 3000);
    socket.addEventListener("open", () => {
      clearTimeout(fallback);
      sourceBadge.textContent = "live (WebSocket)";
      sourceBadge.className = "badge ok";
      sourceBadge.dataset.source = "websocket";
    });
    socket.addEventListener("message", (ev) => {
      let msg;
      try {
        msg = JSON.parse(ev.data);
      } catch {
        return;
      }
      if (msg.type === "positions" && Array.isArray(msg.targets)) accept(msg.targets, msg.t);
    });
    socket.addEventListener("close", () => {
      clearTimeout(fallback);
      if (!stopped) startPolling();
    });
  } catch {
    startPolling();
  }

  // -- the twin --------------------------------------------------------------------------------
  const twinBox = h("div", { testid: "twin" });
  const twinNotice = h("div");
  const control = (action, label) =>
    h(
      "button",
      {
        class: "btn small",
        type: "button",
        testid: `twin-${action}`,
        onClick: async (ev) => {
          const btn = ev.currentTarget;
          btn.disabled = true;
          try {
            await api(`/twin/${action}`, { method: "POST" });
            if (action === "reset") {
              tracks.clear();
              drawTargets();
            }
            twinPoll?.now();
          } catch (err) {
            toastError(err);
          } finally {
            btn.disabled = false;
          }
        },
      },
      label,
    );
  const drawTwin = (tw) => {
    const paused = tw.paused || tw.running === false;
    mount(
      twinBox,
      h(
        "dl",
        { class: "facts" },
        h("dt", null, "State"),
        h(
          "dd",
          null,
          h(
            "span",
            { class: `badge ${paused ? "warn" : "ok"}`, testid: "twin-status" },
            paused ? "paused" : "running",
          ),
        ),
        h("dt", null, "Sim time"),
        h("dd", { class: "num", testid: "twin-time" }, `${fmt(tw.sim_time ?? tw.t, 1)} s`),
        tw.rate_hz ? [h("dt", null, "Frame rate"), h("dd", null, `${fmt(tw.rate_hz, 1)} Hz`)] : null,
        tw.robot_error_rms_m !== undefined && tw.robot_error_rms_m !== null
          ? [
              h("dt", null, "Robot error (RMS)"),
              h("dd", { class: "num", testid: "twin-error" }, `${fmt(tw.robot_error_rms_m * 100, 2)} cm`),
            ]
          : null,
        tw.scene ? [h("dt", null, "Scene"), h("dd", null, tw.scene)] : null,
      ),
      h(
        "div",
        { class: "form-actions" },
        paused ? control("resume", "Resume") : control("pause", "Pause"),
        control("reset", "Reset"),
      ),
    );
    drawTruth(gTruth, tw, tf);
  };
  const twinOff = (err) => {
    drawTruth(gTruth, null, tf);
    mount(
      twinBox,
      infoBox(
        err && err.status && err.status !== 404 && err.status !== 503
          ? `The digital twin's state could not be read: ${err.message}`
          : "The digital twin is not running. Start the service with INTSPACE_SIMULATION=true " +
              "to see the simulated home alive; positions sent by other sources still show here.",
        "twin-off",
      ),
    );
  };
  const showTwin = (tw) => {
    if (tw && tw.enabled === false) twinOff(null);
    else drawTwin(tw);
  };
  let twinPoll = null;
  if (twinElsewhere) {
    const home = spaceById(twin0.value.space_id)?.name || `space ${twin0.value.space_id}`;
    mount(
      twinBox,
      infoBox(
        `The digital twin runs in ${home}, not in ${space.name}: the positions here come from ` +
          `${space.name}'s own cameras. Pick ${home} in the header for the twin's controls.`,
        "twin-elsewhere",
      ),
    );
  } else {
    if (twin0.error || twin0.value?.enabled === false) twinOff(twin0.error);
    else drawTwin(twin0.value);
    twinPoll = poll(() => api("/twin"), { interval: TWIN_MS, delay: true, onValue: showTwin, onError: twinOff });
  }

  // -- layout ----------------------------------------------------------------------------------
  const key = h(
    "div",
    { class: "legend floor-key" },
    h("span", { class: "key-robot" }, "Robot (located)"),
    h("span", { class: "key-person" }, "Person (located)"),
    h("span", { class: "key-truth" }, "Twin's ground truth (dashed)"),
    h("span", { class: "key-cam" }, "Camera and its viewing direction"),
  );
  mount(
    main,
    h(
      "div",
      { class: "grid wide-left" },
      panel(
        null,
        null,
        h(
          "div",
          { class: "panel-head" },
          h(
            "div",
            null,
            h("h2", null, "Live positions on the plan"),
            h("p", null, "Located by the camera network; tracks and 2σ covariance ellipses"),
          ),
          h("div", { class: "form-actions", style: { marginTop: 0 } }, clock, sourceBadge),
        ),
        h("div", { class: "floor-wrap" }, svg),
        h("div", { class: "floor-foot" }, key, scaleNote),
        h(
          "div",
          { class: "floor-foot" },
          h(
            "label",
            { class: "small inline" },
            historyToggle,
            "show ended targets (last 10 min)",
          ),
          historyNote,
        ),
        h(
          "div",
          { class: "floor-foot" },
          cov ? modeButtons : null,
          legendBox,
          readout,
        ),
        heatNote,
      ),
      h(
        "div",
        { class: "grid", style: { alignContent: "start" } },
        panel("Digital twin", "The simulated home: clock and controls", twinBox, twinNotice),
        panel(
          "Targets",
          "Latest position of each target; sd: one standard deviation along the worst direction",
          emptyNote,
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
                  ["Target", "Kind", "State", "x (m)", "y (m)", "sd (mm)"].map((t, i) =>
                    h("th", { class: i >= 3 ? "num" : null }, t),
                  ),
                ),
              ),
              tableBody,
            ),
          ),
        ),
      ),
    ),
  );
  return () => {
    stopped = true;
    zonePoll.stop();
    targetPoll?.stop();
    twinPoll?.stop();
    if (socket) socket.close();
  };
}
