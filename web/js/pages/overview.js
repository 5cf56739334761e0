// Overview: the chosen space, its device counts, service health and a floor plan with the
// cameras.

import { api, currentSpace, inSpace, list, settled } from "../api.js";
import { drawCameras, drawRooms, drawScaleBar, planSvg, planTransform } from "../plan.js";
import { badge, errorBox, facts, h, mount, panel, s, table } from "../ui.js";
import { runCells } from "./calibration.js";
import { cameraCounts } from "./cameras.js";

// [registry path, label, link, whether devices of no space count too]: the Cameras and
// Landmarks pages list the space's devices and those of no space, and so do these counts.
const DEVICES = [
  ["cameras", "Cameras", "#/cameras", true],
  ["projectors", "Projectors", "#/navigation", true],
  ["robots", "Robots", null, true],
  ["landmarks", "Landmarks", "#/landmarks", true],
  ["rooms", "Rooms", null, false],
];

/** A top-down floor plan (world X right, Y up) with the rooms and, for every camera with a
 * pose, its position and the wedge its optical axis points along on the floor. */
function floorPlan(rooms, cameras) {
  const posed = cameras.filter((c) => Array.isArray(c.T_world_camera));
  const pts = [
    ...rooms.flatMap((r) => r.polygon || []),
    ...posed.map((c) => [c.T_world_camera[0][3], c.T_world_camera[1][3]]),
  ];
  if (!pts.length) {
    return h("p", { class: "empty", testid: "floorplan-empty" }, "No rooms or posed cameras yet.");
  }
  const tf = planTransform(pts, { width: 640, minHeight: 360, maxHeight: 360, margin: 0, pad: 24 });
  const gRooms = s("g");
  const gCams = s("g");
  drawRooms(gRooms, rooms, tf);
  drawScaleBar(gRooms, tf, { minPx: 50 });
  drawCameras(gCams, posed, tf, { view: "wedge" });
  return planSvg(
    tf,
    { className: "plot floorplan", label: "Floor plan with cameras", testid: "floorplan" },
    gRooms,
    gCams,
  );
}

export async function renderOverview(main) {
  const [health, home, spaces, runs, ...counts] = await Promise.all(
    [
      api("/health"),
      api("/home/status"),
      list("/spaces", { limit: 20 }),
      list("/calibration-runs", { limit: 20 }),
      ...DEVICES.map(([path, , , unassigned]) =>
        list(inSpace(`/${path}`, { unassigned }), { limit: 200 }),
      ),
    ].map(settled),
  );
  // One error box for the whole page when every registry read was refused (not signed in).
  const refused = [spaces, ...counts].every((r) => r.error && r.error.status === 401);
  if (refused) throw spaces.error;
  const rooms = counts[DEVICES.findIndex(([k]) => k === "rooms")].value?.items || [];
  const cameras = counts[0].value?.items || [];
  mount(
    main,
    deviceStats(counts),
    h(
      "div",
      { class: "grid wide-left" },
      panel(
        "Floor plan",
        "Rooms and the cameras with a calibrated pose, seen from above",
        floorPlan(rooms, cameras),
      ),
      h("div", { class: "grid" }, servicePanel(health), homePanel(home), spacePanel(spaces)),
    ),
    recentRunsPanel(runs, cameras),
  );
}

/** The count of each kind of device in the space (`counts`: one read per DEVICES entry). */
function deviceStats(counts) {
  return h(
    "div",
    { class: "stats", testid: "device-counts" },
    DEVICES.map(([key, label, href], i) => {
      const r = counts[i];
      let sub = "";
      if (key === "cameras" && r.value) {
        // What the Cameras page's Status and Health columns say, counted.
        const n = cameraCounts(r.value.items);
        sub = `${n.calibrated} calibrated · ${n.online} online`;
      }
      return h(
        href ? "a" : "div",
        { class: "stat", href, testid: `count-${key}` },
        h("div", { class: "label" }, label),
        h("div", { class: "value" }, r.error ? "–" : String(r.value.total)),
        h("div", { class: "sub" }, r.error ? r.error.title || "unavailable" : sub || "\u00a0"),
      );
    }),
  );
}

/** The service's health: API, database, storage, schema, reads, twin and 3D scene. */
function servicePanel(health) {
  const hv = health.value || {};
  const rows = [
    ["Status", badge(hv.status, hv.status === "ok" ? "ok" : "bad")],
    ["Version", hv.version || "–", { class: "mono", testid: "health-version" }],
    ["Database", describeDatabase(hv.database), { testid: "health-database" }],
    ["Storage", hv.storage === "ok" ? "working" : hv.storage || "–", { testid: "health-storage" }],
    ["Schema", hv.schema_revision ? `revision ${hv.schema_revision}` : "–", { class: "mono" }],
    ["Reads", hv.public_reads ? "open to anyone" : "need a token"],
    ["Digital twin", hv.simulation ? "running in this service" : "off"],
    ["3D scene", hv.scene ? "served by this process" : "not here", { testid: "health-scene" }],
  ];
  return panel(
    "Service",
    "Health of the API and its database",
    health.error ? errorBox(health.error, "health-error") : facts({ testid: "health" }, rows),
  );
}

/** The space shown, and the others registered. */
function spacePanel(spaces) {
  const space = currentSpace();
  const others = (spaces.value ? spaces.value.items : []).filter((sp) => sp.id !== space?.id);
  let body;
  if (spaces.error) body = errorBox(spaces.error);
  else if (!space) body = h("p", { class: "empty", testid: "space" }, "No space defined yet.");
  else {
    body = h(
      "div",
      { testid: "space" },
      h("h3", { class: "space-name" }, space.name),
      space.description ? h("p", { class: "muted small" }, space.description) : null,
      others.length
        ? h(
            "p",
            { class: "small muted", testid: "other-spaces" },
            `Also registered: ${others.map((sp) => sp.name).join(", ")}. ` +
              "Pick the space to show in the header; every page shows only its devices.",
          )
        : null,
    );
  }
  return panel("Space", null, body);
}

/** The space's newest runs: those of its cameras, and those of no camera (network, projector,
 * arm). */
function recentRunsPanel(runs, cameras) {
  const cameraIds = new Set(cameras.map((c) => c.id));
  const spaceRuns = (runs.value?.items || [])
    .filter((r) => !r.camera_id || cameraIds.has(r.camera_id))
    .slice(0, 6);
  let body;
  if (runs.error) body = errorBox(runs.error);
  else if (!spaceRuns.length) body = h("p", { class: "empty" }, "No calibration runs yet.");
  else body = h("div", { class: "table-wrap" }, recentRunsTable(spaceRuns, cameras));
  return panel("Recent calibration runs", null, body);
}

function recentRunsTable(runs, cameras) {
  const head = ["Run", "Camera", "Status", "RMS (px)", "fx (px)", "Created"];
  const row = (r) => {
    const cells = runCells(r, cameras);
    return h("tr", null, cells.run, cells.camera, cells.status, cells.rms, cells.fx, cells.created);
  };
  const columns = head.map((t, i) => [
    t,
    { class: i === 3 || i === 4 ? "num" : null, scope: "col" },
  ]);
  return table({ testid: "recent-runs" }, columns, runs.map(row));
}

/** The home integration's panel: the MQTT broker's connection and Frigate's (spec 09). */
function homePanel(home) {
  const broker = (b, id) =>
    b
      ? [
          h(
            "dd",
            { testid: `${id}-state` },
            badge(b.connected ? "connected" : "disconnected", b.connected ? "ok" : "bad"),
          ),
          h("dt", null, "Since"),
          h(
            "dd",
            { class: "small", testid: `${id}-since` },
            b.since ? new Date(b.since * 1000).toLocaleString() : "–",
          ),
          h("dt", null, "Broker"),
          h("dd", { class: "mono small", testid: `${id}-url` }, b.url),
          h("dt", null, "Dropped"),
          h("dd", { testid: `${id}-dropped` }, `${b.dropped} (queued ${b.queued})`),
        ]
      : [h("dd", { testid: `${id}-state` }, "off")];
  const v = home.value || {};
  return panel(
    "Home",
    "MQTT for Home Assistant, and Frigate as a source",
    home.error
      ? errorBox(home.error, "home-error")
      : h(
          "dl",
          { class: "facts", testid: "home" },
          h("dt", null, "MQTT"),
          ...broker(v.mqtt, "mqtt"),
          h("dt", null, "Frigate"),
          ...(v.frigate
            ? [
                ...broker(v.frigate.broker, "frigate"),
                h("dt", null, "Objects held"),
                h(
                  "dd",
                  { testid: "frigate-held" },
                  `${v.frigate.held} (${v.frigate.fed} reports fed)`,
                ),
              ]
            : [h("dd", { testid: "frigate-state" }, "off")]),
        ),
  );
}

function describeDatabase(db) {
  if (db === null || db === undefined) return "–";
  if (typeof db === "string") return db;
  const parts = [
    db.status,
    db.backend || db.dialect || db.name,
    db.revision ? `revision ${db.revision}` : null,
  ];
  return parts.filter(Boolean).join(" · ") || JSON.stringify(db);
}
