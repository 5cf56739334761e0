// Cameras: the chosen space's table with an add form, and one camera's health, latest image,
// intrinsics, history and exports.

import { api, busy, currentSpace, download, inSpace, list, poll, spaceById } from "../api.js";
import { barChart } from "../plot.js";
import { placePanel } from "./placement.js";
import {
  badge,
  errorBox,
  fmt,
  h,
  matrixTable,
  mount,
  panel,
  sig,
  toast,
  toastError,
  when,
} from "../ui.js";

const DIST_NAMES = ["k1", "k2", "p1", "p2", "k3"];
const LIVE_MS = 500; // about 2 frames a second
const LIVE_RETRY_MS = 5000; // when there is no frame (no twin): look again now and then
const HEALTH_MS = 2000; // the camera's health is read again this often

/**
 * The camera's latest frame with its detections drawn, refreshed about twice a second. The image
 * is fetched (with the session cookie) and shown from a blob URL once decoded, so a frame
 * never flickers in half-loaded. Returns {panel, stop}.
 */
function liveView(id) {
  const img = h("img", {
    class: "live-frame",
    alt: "Latest frame of this camera with detections drawn",
    testid: "camera-live-image",
    hidden: true,
  });
  const status = h("span", { class: "small muted", testid: "camera-live-status" }, "Loading…");
  const missing = h("div");
  let url = null;
  let frames = 0;
  // A frame decoded from the blob before it is shown, so the image never flickers half-loaded.
  const show = async ({ blob, t }) => {
    const next = URL.createObjectURL(blob);
    await new Promise((resolve) => {
      img.onload = resolve;
      img.onerror = resolve;
      img.src = next;
    });
    if (url) URL.revokeObjectURL(url);
    url = next;
    frames += 1;
    img.hidden = false;
    img.dataset.frames = String(frames);
    mount(missing);
    status.textContent =
      `Refreshed ${new Date().toLocaleTimeString()}` + (t ? ` · sim time ${Number(t).toFixed(1)} s` : "");
  };
  const frame = async () => {
    if (document.visibilityState === "hidden") return null;
    const response = await fetch(`/api/v1/cameras/${id}/frame.jpg?overlay=true`, {
      headers: { Accept: "image/jpeg" },
      credentials: "same-origin",
    });
    if (!response.ok) {
      throw Object.assign(new Error("no frame"), {
        status: response.status,
        reason: await reasonOf(response),
      });
    }
    const t = response.headers.get("x-sim-time") || response.headers.get("x-frame-time");
    return { blob: await response.blob(), t };
  };
  // No frame (no twin, no node yet): look again less and less often, up to LIVE_RETRY_MS.
  const live = poll(frame, {
    interval: LIVE_MS,
    maxInterval: LIVE_RETRY_MS,
    onValue: (got) => (got ? show(got) : undefined),
    onError: (err) => {
      if (err.reason === undefined) {
        status.textContent = `The service did not answer (${err.message}).`;
        return;
      }
      img.hidden = true;
      status.textContent = "";
      mount(missing, noImage(err.status, err.reason));
    },
  });
  return {
    panel: panel(
      "Live image",
      "The latest frame with the detections drawn (robot marker, people), about 2 per second",
      img,
      missing,
      h("div", { style: { marginTop: "8px" } }, status),
    ),
    stop: () => {
      live.stop();
      if (url) URL.revokeObjectURL(url);
    },
  };
}

/** The service's reason for an answer without an image (its problem detail), or "". */
async function reasonOf(response) {
  try {
    const body = await response.json();
    return typeof body.detail === "string" ? body.detail : "";
  } catch {
    return "";
  }
}

function noImage(status, reason) {
  return h(
    "p",
    { class: "empty", testid: "camera-live-missing" },
    status === 404 ? "No image yet" : `No image (HTTP ${status})`,
    reason ? `: ${reason}.` : ".",
    status === 404
      ? h(
          "span",
          { class: "small muted", style: { display: "block", marginTop: "6px" } },
          "A camera's latest image is shown once its source delivers one: the digital twin " +
            "for its own cameras, a camera node for the others.",
        )
      : null,
  );
}

function cameraStatus(c) {
  return c.status || (c.K ? "calibrated" : "uncalibrated");
}

/** Count cameras as the table shows them: calibrated (Status) and online (Health). */
export function cameraCounts(cameras) {
  return {
    calibrated: cameras.filter((c) => cameraStatus(c) === "calibrated").length,
    online: cameras.filter((c) => c.health?.status === "online").length,
  };
}

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

function clockTime(t) {
  return t === null || t === undefined
    ? "–"
    : new Date(t * 1000).toLocaleTimeString([], { hour12: false });
}

/** The camera's health facts: status since when, frame rate, stalls, reconnects, drops and the
 * clock offset its source reports (a camera node's heartbeat; the twin's loop for its own). */
function healthFacts(health) {
  const hl = health || { status: "offline" };
  const row = (label, testid, value) => [
    h("dt", null, label),
    h("dd", { class: "num", testid: `camera-health-${testid}` }, value),
  ];
  const count = (v) => (v === null || v === undefined ? "–" : String(v));
  return h(
    "dl",
    { class: "facts", testid: "camera-health" },
    h("dt", null, "Status"),
    h("dd", null, healthBadge(hl, "camera-health-status")),
    row(
      "Since",
      "since",
      hl.since ? `${clockTime(hl.since)} (${ago(hl.since)})` : "never reported",
    ),
    row("Frame rate", "fps", hl.fps === null || hl.fps === undefined ? "–" : `${fmt(hl.fps, 1)} /s`),
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
  );
}

/** The camera's health, read again every HEALTH_MS. Returns {panel, stop}. */
function healthView(id, initial) {
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

function addCameraForm(space, onCreated) {
  const error = h("div");
  const name = h("input", {
    id: "cam-name",
    name: "name",
    required: true,
    maxlength: 200,
    placeholder: "e.g. ceiling-kitchen",
    testid: "camera-name",
  });
  const width = h("input", {
    id: "cam-width",
    name: "width",
    type: "number",
    min: 1,
    required: true,
    value: "1280",
    testid: "camera-width",
  });
  const height = h("input", {
    id: "cam-height",
    name: "height",
    type: "number",
    min: 1,
    required: true,
    value: "720",
    testid: "camera-height",
  });
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "camera-create" },
    "Add camera",
  );
  const form = h(
    "form",
    {
      testid: "camera-form",
      onSubmit: async (ev) => {
        ev.preventDefault();
        mount(error);
        try {
          await busy(submit, async () => {
            const cam = await api("/cameras", {
              method: "POST",
              json: {
                name: name.value.trim(),
                width: Number(width.value),
                height: Number(height.value),
                space_id: space ? space.id : null,
              },
            });
            toast(`Camera “${cam.name}” added`);
            form.reset();
            onCreated(cam);
          });
        } catch (err) {
          mount(error, errorBox(err, "camera-form-error"));
        }
      },
    },
    h(
      "div",
      { class: "form-grid" },
      h("label", { for: "cam-name" }, "Name", name),
      h("label", { for: "cam-width" }, "Image width (px)", width),
      h("label", { for: "cam-height" }, "Image height (px)", height),
      h("div", null, submit),
    ),
    error,
  );
  return form;
}

export async function renderCameras(main) {
  const space = currentSpace();
  const { items, total } = await list(inSpace("/cameras", { unassigned: true }), { limit: 200 });
  const table = h(
    "table",
    { testid: "camera-table" },
    h(
      "thead",
      null,
      h(
        "tr",
        null,
        ["Name", "Image", "Status", "Health", "fx", "fy", "cx", "cy", "Pose", "Updated"].map(
          (t, i) => h("th", { class: i >= 4 && i <= 7 ? "num" : null, scope: "col" }, t),
        ),
      ),
    ),
    h(
      "tbody",
      null,
      items.map((c) =>
        h(
          "tr",
          {
            class: "link-row",
            testid: `camera-row-${c.id}`,
            onClick: (ev) => {
              if (ev.target.tagName !== "A") location.hash = `#/cameras/${c.id}`;
            },
          },
          h(
            "td",
            null,
            h("a", { href: `#/cameras/${c.id}` }, c.name),
            space && c.space_id === null
              ? h("span", { class: "small muted", testid: `camera-no-space-${c.id}` }, " (no space)")
              : null,
          ),
          h("td", { class: "num" }, `${c.width} × ${c.height}`),
          h("td", null, badge(cameraStatus(c))),
          h(
            "td",
            { title: c.health?.fps ? `${fmt(c.health.fps, 1)} frames/s` : null },
            healthBadge(c.health, `camera-health-${c.id}`),
          ),
          [0, 4, 2, 5].map((k) =>
            h("td", { class: "num" }, c.K ? fmt(c.K[Math.floor(k / 3)][k % 3], 2) : "–"),
          ),
          h("td", null, c.T_world_camera ? "calibrated" : h("span", { class: "muted" }, "unknown")),
          h("td", { class: "small muted" }, when(c.updated_at)),
        ),
      ),
    ),
  );
  mount(
    main,
    panel(
      "Add a camera",
      space
        ? `Register a camera of ${space.name} by name and image size; calibrate it afterwards`
        : "Register a camera by name and image size; calibrate it afterwards",
      addCameraForm(space, (cam) => {
        location.hash = `#/cameras/${cam.id}`;
      }),
    ),
    panel(
      space ? `Cameras of ${space.name} (${total})` : `Cameras (${total})`,
      "Click a camera for its health, latest image, intrinsics, calibration history and exports",
      items.length
        ? h(
            "div",
            { class: "table-wrap" },
            table,
            total > items.length
              ? h("p", { class: "small muted" }, `Showing the first ${items.length} of ${total}.`)
              : null,
          )
        : h(
            "p",
            { class: "empty", testid: "camera-table-empty" },
            space ? `No cameras in ${space.name} yet. Add one above.` : "No cameras yet. Add one above.",
          ),
    ),
  );
}

function stdOf(std, name, index) {
  if (!std) return null;
  if (Array.isArray(std)) return std[index];
  return std[name];
}

/** The intrinsics as a list: value ± standard deviation. */
export function intrinsicsFacts(K, dist, std, testPrefix) {
  const entries = [
    ["fx", K[0][0], 0],
    ["fy", K[1][1], 1],
    ["cx", K[0][2], 2],
    ["cy", K[1][2], 3],
    ["skew", K[0][1], 4],
  ];
  const rows = entries.map(([name, v, i]) => {
    const sd = stdOf(std, name, i);
    return [
      h("dt", null, name),
      h(
        "dd",
        { class: "num", testid: `${testPrefix}-${name}` },
        fmt(v, 3),
        sd ? h("span", { class: "muted" }, ` ± ${fmt(sd, 3)}`) : null,
        " px",
      ),
    ];
  });
  const distRows = (dist || []).map((v, i) => {
    const name = DIST_NAMES[i] || `d${i}`;
    const sd = stdOf(std, name, 5 + i);
    return [
      h("dt", null, name),
      h(
        "dd",
        { class: "num", testid: `${testPrefix}-${name}` },
        sig(v, 6),
        sd ? h("span", { class: "muted" }, ` ± ${sig(sd, 2)}`) : null,
      ),
    ];
  });
  return h("dl", { class: "facts", testid: `${testPrefix}-intrinsics` }, rows, distRows);
}

/** The run that set the camera's calibration; a failure is reported next to the intrinsics. */
async function fetchRun(id) {
  try {
    return { run: await api(`/calibration-runs/${id}`) };
  } catch (error) {
    return { error };
  }
}

export async function renderCamera(main, [id], _query, setTitle) {
  const cam = await api(`/cameras/${id}`);
  setTitle(cam.name);
  const [historyResult, runResult] = await Promise.all([
    api(`/cameras/${id}/calibrations`).then(
      (v) => ({ v }),
      (e) => ({ e }),
    ),
    cam.calibration_run_id ? fetchRun(cam.calibration_run_id) : {},
  ]);
  const run = runResult.run;

  const exportButton = (format, label) =>
    h(
      "button",
      {
        class: "btn",
        type: "button",
        testid: `export-${format}`,
        disabled: !cam.K,
        title: cam.K ? null : "Calibrate the camera first",
        onClick: async () => {
          try {
            await download(
              `/cameras/${id}/calibration.yaml?format=${format}`,
              `${cam.name}-${format}.yaml`,
            );
          } catch (err) {
            toastError(err);
          }
        },
      },
      label,
    );

  const actions = h(
    "div",
    { class: "form-actions" },
    h(
      "a",
      { class: "btn primary", href: `#/calibration?camera=${id}`, testid: "calibrate-camera" },
      "Calibrate…",
    ),
    exportButton("opencv", "Export OpenCV YAML"),
    exportButton("ros", "Export ROS camera_info"),
    h(
      "button",
      {
        class: "btn danger",
        type: "button",
        testid: "delete-camera",
        onClick: async () => {
          if (!confirm(`Delete camera “${cam.name}” and its calibration history?`)) return;
          try {
            await api(`/cameras/${id}`, { method: "DELETE" });
            toast(`Camera “${cam.name}” deleted`);
            location.hash = "#/cameras";
          } catch (err) {
            toastError(err);
          }
        },
      },
      "Delete",
    ),
  );

  const std = run?.result?.std_intrinsics;
  const intrinsics = panel(
    "Intrinsics",
    cam.K
      ? "Calibration matrix K and distortion (OpenCV order)" +
          (run?.result?.rms ? `, RMS ${fmt(run.result.rms, 3)} px` : "")
      : null,
    cam.K
      ? h(
          "div",
          { class: "grid two" },
          h(
            "div",
            null,
            h("h3", { style: { marginBottom: "8px" } }, "K (pixels)"),
            matrixTable(cam.K, 3, "camera-K"),
          ),
          intrinsicsFacts(cam.K, cam.dist, std, "camera"),
          runResult.error ? errorBox(runResult.error, "camera-run-error") : null,
        )
      : h(
          "p",
          { class: "empty", testid: "camera-uncalibrated" },
          "Not calibrated yet. Start a calibration run to estimate K and the distortion.",
        ),
  );

  const pose = panel(
    "Pose in the space",
    "Camera-to-world transform (OpenCV camera axes; world Z up, metres)",
    cam.T_world_camera
      ? matrixTable(cam.T_world_camera, 4, "camera-pose")
      : h(
          "p",
          { class: "empty", testid: "camera-no-pose" },
          "No calibrated pose: the 3D scene shows this camera parked beside the floor plan.",
        ),
  );

  const details = panel(
    "Camera",
    null,
    h(
      "dl",
      { class: "facts", testid: "camera-facts" },
      h("dt", null, "Status"),
      h("dd", null, badge(cameraStatus(cam))),
      h("dt", null, "Space"),
      h("dd", { testid: "camera-space" }, spaceName(cam.space_id)),
      h("dt", null, "Image size"),
      h("dd", { class: "num" }, `${cam.width} × ${cam.height} px`),
      h("dt", null, "Calibrated by"),
      h(
        "dd",
        null,
        cam.calibration_run_id
          ? h(
              "a",
              { href: `#/calibration/runs/${cam.calibration_run_id}` },
              `run #${cam.calibration_run_id}`,
            )
          : "–",
      ),
      h("dt", null, "Created"),
      h("dd", null, when(cam.created_at)),
      h("dt", null, "Updated"),
      h("dd", null, when(cam.updated_at)),
    ),
    actions,
  );

  let history;
  if (historyResult.e) {
    history = errorBox(historyResult.e, "history-error");
  } else {
    const rows = Array.isArray(historyResult.v) ? historyResult.v : historyResult.v.items || [];
    history = rows.length
      ? h(
          "div",
          { class: "table-wrap" },
          h(
            "table",
            { testid: "calibration-history" },
            h(
              "thead",
              null,
              h(
                "tr",
                null,
                ["Applied", "Run", "fx", "fy", "cx", "cy", "RMS (px)"].map((t, i) =>
                  h("th", { class: i >= 2 ? "num" : null }, t),
                ),
              ),
            ),
            h(
              "tbody",
              null,
              rows.map((c) =>
                h(
                  "tr",
                  null,
                  h("td", { class: "small" }, when(c.created_at)),
                  h(
                    "td",
                    null,
                    c.calibration_run_id
                      ? h(
                          "a",
                          { href: `#/calibration/runs/${c.calibration_run_id}` },
                          `#${c.calibration_run_id}`,
                        )
                      : "–",
                  ),
                  [c.K[0][0], c.K[1][1], c.K[0][2], c.K[1][2]].map((v) =>
                    h("td", { class: "num" }, fmt(v, 2)),
                  ),
                  h("td", { class: "num" }, fmt(c.rms, 4)),
                ),
              ),
            ),
          ),
        )
      : h(
          "p",
          { class: "empty", testid: "calibration-history-empty" },
          "No calibration applied yet.",
        );
  }

  const residuals = run?.result?.per_view_rms?.length
    ? panel(
        "Residuals of the applied calibration",
        `Run #${run.id}: RMS reprojection error per view`,
        barChart(run.result.per_view_rms, {
          reference: run.result.rms,
          title: "RMS reprojection error per view",
        }),
      )
    : null;

  const live = liveView(id);
  const health = healthView(id, cam.health);
  const place = await placePanel(cam, () => location.reload());
  mount(
    main,
    h(
      "div",
      { class: "grid wide-left", style: { alignItems: "start" } },
      live.panel,
      h("div", { class: "grid" }, health.panel, details),
    ),
    h("div", { class: "grid wide-left" }, intrinsics, pose),
    place,
    residuals,
    panel("Calibration history", "Every calibration applied to this camera, newest first", history),
  );
  return () => {
    live.stop();
    health.stop();
  };
}

function spaceName(spaceId) {
  if (spaceId === null || spaceId === undefined) return "none";
  return spaceById(spaceId)?.name || `space ${spaceId}`;
}
