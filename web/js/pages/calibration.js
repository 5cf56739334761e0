// Calibration runs: start one (chessboard photos or a correspondences file), watch it, apply it.

import { api, inSpace, list, poll } from "../api.js";
import { lineChart } from "../chart.js";
import { barChart } from "../plot.js";
import {
  duration,
  errorBox,
  fmt,
  h,
  infoBox,
  matrixTable,
  mount,
  panel,
  statusBadge,
  toast,
  when,
} from "../ui.js";
import { intrinsicsFacts } from "./cameras.js";

const DISTORTION_MODELS = [
  ["none", "None"],
  ["k1", "k1"],
  ["k1k2", "k1, k2"],
  ["k1k2p1p2", "k1, k2, p1, p2"],
  ["k1k2p1p2k3", "k1, k2, p1, p2, k3"],
];
const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);
// The acceptance targets of a network calibration in the default simulated home (spec 02):
// focal length within 1 %, position within 2 cm, orientation within 0.3 degrees.
const NETWORK_TARGETS = { focal_pct: 1, position_cm: 2, rotation_deg: 0.3 };
const POLL_MS = 600;

/**
 * Read a correspondences file: {"object_points": views of Nx3 (or one Nx3 shared by all views),
 * "image_points": views of Nx2, "image_size": [w, h] (optional)}. Throws with a readable message.
 */
export function parseCorrespondences(text, fallbackSize) {
  let data;
  try {
    data = JSON.parse(text);
  } catch (err) {
    throw new Error(`The file is not valid JSON (${err.message}).`);
  }
  const img = data.image_points;
  let obj = data.object_points;
  if (!Array.isArray(img) || !img.length || !Array.isArray(img[0]) || !Array.isArray(img[0][0])) {
    throw new Error(
      'The file needs "image_points": a list of views, each a list of [u, v] pixels.',
    );
  }
  if (Array.isArray(obj) && obj.length && typeof obj[0][0] === "number") obj = img.map(() => obj);
  if (!Array.isArray(obj) || obj.length !== img.length) {
    throw new Error(
      'The file needs "object_points": one list of [X, Y, Z] per view (or one shared list).',
    );
  }
  img.forEach((view, i) => {
    if (view.length !== obj[i].length) {
      throw new Error(
        `View ${i + 1} has ${view.length} image points but ${obj[i].length} object points.`,
      );
    }
  });
  const size = data.image_size || fallbackSize;
  return { object_points: obj, image_points: img, image_size: size };
}

function runsTable(runs, cameras) {
  const name = (id) => cameras.find((c) => c.id === id)?.name || (id ? `camera ${id}` : "–");
  return h(
    "table",
    { testid: "run-table" },
    h(
      "thead",
      null,
      h(
        "tr",
        null,
        ["Run", "Camera", "Kind", "Status", "RMS (px)", "fx", "Created", "Duration"].map((t, i) =>
          h("th", { class: i === 4 || i === 5 ? "num" : null }, t),
        ),
      ),
    ),
    h(
      "tbody",
      null,
      runs.map((r) =>
        h(
          "tr",
          {
            class: "link-row",
            testid: `run-row-${r.id}`,
            onClick: (ev) => {
              if (ev.target.tagName !== "A") location.hash = `#/calibration/runs/${r.id}`;
            },
          },
          h("td", null, h("a", { href: `#/calibration/runs/${r.id}` }, `#${r.id}`)),
          h(
            "td",
            null,
            r.camera_id ? h("a", { href: `#/cameras/${r.camera_id}` }, name(r.camera_id)) : "–",
          ),
          h("td", null, [
            r.kind,
            r.source ? h("span", { class: "muted small" }, ` · ${r.source}`) : null,
          ]),
          h("td", null, statusBadge(r.status)),
          h("td", { class: "num" }, fmt(r.result?.rms, 4)),
          h("td", { class: "num" }, r.result?.K ? fmt(r.result.K[0][0], 2) : "–"),
          h("td", { class: "small muted" }, when(r.created_at)),
          h("td", { class: "small muted" }, duration(r.started_at, r.finished_at)),
        ),
      ),
    ),
  );
}

function startForm(cameras, preselect) {
  const error = h("div", { "aria-live": "assertive" });
  const camera = h(
    "select",
    { id: "run-camera", name: "camera_id", required: true, testid: "run-camera" },
    cameras.map((c) =>
      h(
        "option",
        { value: String(c.id), selected: String(c.id) === preselect },
        `${c.name} (${c.width}×${c.height})`,
      ),
    ),
  );
  const source = (value, label, checked) =>
    h(
      "label",
      null,
      h("input", { type: "radio", name: "source", value, checked, testid: `run-source-${value}` }),
      label,
    );
  const sources = h(
    "div",
    { class: "segmented", role: "radiogroup", "aria-label": "Input" },
    source("json", "Correspondences file (JSON)", true),
    source("photos", "Chessboard photos", false),
  );

  const jsonFile = h("input", {
    id: "run-json-file",
    type: "file",
    accept: "application/json,.json",
    testid: "run-json-file",
  });
  const jsonSummary = h(
    "p",
    { class: "small muted", testid: "json-summary" },
    "Pick a JSON file with object_points, image_points and image_size.",
  );
  let parsed = null;
  jsonFile.addEventListener("change", async () => {
    parsed = null;
    mount(error);
    const file = jsonFile.files[0];
    if (!file) return;
    try {
      const cam = cameras.find((c) => String(c.id) === camera.value);
      parsed = parseCorrespondences(await file.text(), cam ? [cam.width, cam.height] : undefined);
      const n = parsed.image_points.reduce((a, v) => a + v.length, 0);
      const size = parsed.image_size ? parsed.image_size.join(" × ") : "size from the camera";
      const views = parsed.image_points.length;
      jsonSummary.textContent = `${file.name}: ${views} views, ${n} points, image ${size}`;
    } catch (err) {
      jsonSummary.textContent = file.name;
      mount(
        error,
        errorBox({ title: "Cannot use this file", detail: err.message }, "run-form-error"),
      );
    }
  });
  const photos = h("input", {
    id: "run-files",
    type: "file",
    multiple: true,
    accept: "image/png,image/jpeg,image/bmp,image/tiff",
    testid: "run-files",
  });
  const board = h("input", {
    id: "run-chessboard",
    value: "9x6",
    pattern: "\\d+\\s*[xX×]\\s*\\d+",
    title: "inner corners, columns x rows, e.g. 9x6",
    testid: "run-chessboard",
  });
  const square = h("input", {
    id: "run-square",
    type: "number",
    step: "any",
    min: "0",
    value: "0.025",
    testid: "run-square",
  });

  const jsonPane = h(
    "div",
    { class: "form-grid wide", testid: "pane-json" },
    h("label", { for: "run-json-file" }, "Correspondences file", jsonFile),
    jsonSummary,
  );
  const photoPane = h(
    "div",
    { class: "form-grid wide", testid: "pane-photos", hidden: true },
    h("label", { for: "run-files" }, "Chessboard photos", photos),
    h("label", { for: "run-chessboard" }, "Inner corners (cols × rows)", board),
    h("label", { for: "run-square" }, "Square size (m)", square),
  );
  sources.addEventListener("change", () => {
    const isJson = sources.querySelector("input:checked").value === "json";
    jsonPane.hidden = !isJson;
    photoPane.hidden = isJson;
    mount(error);
  });

  const distortion = h(
    "select",
    { id: "run-distortion", testid: "run-distortion" },
    DISTORTION_MODELS.map(([v, label]) =>
      h("option", { value: v, selected: v === "k1k2p1p2" }, label),
    ),
  );
  const skew = h("input", { id: "run-skew", type: "checkbox", testid: "run-skew" });
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "run-submit" },
    "Start calibration",
  );

  const form = h(
    "form",
    {
      testid: "run-form",
      onSubmit: async (ev) => {
        ev.preventDefault();
        mount(error);
        const isJson = sources.querySelector("input:checked").value === "json";
        const options = { skew: skew.checked, distortion: distortion.value };
        try {
          submit.disabled = true;
          let run;
          if (isJson) {
            if (!parsed) throw new Error("Pick a correspondences file first.");
            const cam = cameras.find((c) => String(c.id) === camera.value);
            run = await api("/calibration-runs", {
              method: "POST",
              json: {
                kind: "intrinsics",
                camera_id: Number(camera.value),
                image_size: parsed.image_size || [cam.width, cam.height],
                object_points: parsed.object_points,
                image_points: parsed.image_points,
                options,
              },
            });
          } else {
            if (!photos.files.length) throw new Error("Pick the chessboard photos first.");
            const fd = new FormData();
            fd.append("camera_id", camera.value);
            fd.append("chessboard", board.value.replace(/\s+/g, "").replace("×", "x"));
            fd.append("square", square.value);
            fd.append("distortion", options.distortion);
            fd.append("skew", String(options.skew));
            for (const f of photos.files) fd.append("files", f, f.name);
            run = await api("/calibration-runs/upload", { method: "POST", form: fd });
          }
          toast(`Calibration run #${run.id} started`);
          location.hash = `#/calibration/runs/${run.id}`;
        } catch (err) {
          mount(
            error,
            errorBox(
              err.title ? err : { title: "Cannot start the run", detail: err.message },
              "run-form-error",
            ),
          );
        } finally {
          submit.disabled = false;
        }
      },
    },
    h(
      "div",
      { class: "form-row" },
      h("label", { for: "run-camera" }, "Camera", camera),
      h(
        "div",
        null,
        h(
          "span",
          {
            class: "small",
            style: {
              display: "block",
              marginBottom: "5px",
              fontWeight: 550,
              color: "var(--ink-2)",
            },
          },
          "Input",
        ),
        sources,
      ),
    ),
    h("div", { style: { marginTop: "14px" } }, jsonPane, photoPane),
    h(
      "fieldset",
      { style: { marginTop: "14px" } },
      h("legend", null, "Model"),
      h(
        "div",
        { class: "form-grid" },
        h("label", { for: "run-distortion" }, "Distortion", distortion),
        h("label", { class: "inline", for: "run-skew" }, skew, "Estimate skew"),
      ),
    ),
    h("div", { class: "form-actions" }, submit),
    error,
  );
  return form;
}

/** Start a run of kind "network": the twin drives the robot's marker past every camera. */
function networkPanel() {
  const error = h("div", { "aria-live": "assertive" });
  const seed = h("input", {
    id: "network-seed",
    type: "number",
    min: 0,
    step: 1,
    value: "0",
    testid: "network-seed",
  });
  // The drive's length (simulated minutes, at most 30): spec 02's drive is 5 minutes; a
  // longer one gives a camera seen from few stops more of them (the run's bound says how much).
  const minutes = h("input", {
    id: "network-minutes",
    type: "number",
    min: 0.5,
    max: 30,
    step: 0.5,
    value: "5",
    testid: "network-minutes",
  });
  const button = h(
    "button",
    {
      class: "btn primary",
      type: "button",
      testid: "network-calibrate",
      onClick: async () => {
        mount(error);
        button.disabled = true;
        try {
          const run = await api("/calibration-runs", {
            method: "POST",
            json: {
              kind: "network",
              options: {
                seed: Number(seed.value) || 0,
                minutes: minutes.value === "" ? 5 : Number(minutes.value),
              },
            },
          });
          toast(`Network calibration run #${run.id} started`);
          location.hash = `#/calibration/runs/${run.id}`;
        } catch (err) {
          mount(error, errorBox(err, "network-error"));
        } finally {
          button.disabled = false;
        }
      },
    },
    "Calibrate the camera network",
  );
  return panel(
    "Network calibration",
    "Every ceiling camera at once: each camera's intrinsics from a chessboard shown to it, " +
      "then the digital twin drives the robot's marker over the floor (its mast raised) and " +
      "every camera's pose comes from a joint refinement with the odometry",
    h(
      "div",
      { class: "form-grid" },
      h("label", { for: "network-seed" }, "Seed (noise and drive)", seed),
      h("label", { for: "network-minutes" }, "Drive (minutes, at most 30)", minutes),
      h("div", null, button),
    ),
    error,
  );
}

export async function renderCalibration(main, _params, query) {
  const [{ items: cameras }, runs] = await Promise.all([
    list(inSpace("/cameras", { unassigned: true }), { limit: 200 }),
    list("/calibration-runs", { limit: 50 }).then(
      (v) => ({ v }),
      (e) => ({ e }),
    ),
  ]);
  // A camera linked from its page is offered even when it is of another space than the one
  // picked; the runs shown are the space's cameras' and those of no camera.
  const linked = Number(query.get("camera"));
  if (linked && !cameras.some((c) => c.id === linked)) {
    try {
      cameras.push(await api(`/cameras/${linked}`));
    } catch {
      /* gone: the form offers the space's cameras */
    }
  }
  if (runs.v) {
    const ids = new Set(cameras.map((c) => c.id));
    const kept = runs.v.items.filter((r) => !r.camera_id || ids.has(r.camera_id));
    // Of the newest 50 runs, those of this space: their count is all the page knows.
    if (kept.length < runs.v.items.length) runs.v.total = kept.length;
    runs.v.items = kept;
  }
  const runsBody = runs.e
    ? errorBox(runs.e, "runs-error")
    : runs.v.items.length
      ? h(
          "div",
          { class: "table-wrap" },
          runsTable(runs.v.items, cameras),
          runs.v.total > runs.v.items.length
            ? h(
                "p",
                { class: "small muted" },
                `Showing the newest ${runs.v.items.length} of ${runs.v.total}.`,
              )
            : null,
        )
      : h("p", { class: "empty", testid: "run-table-empty" }, "No calibration runs yet.");
  mount(
    main,
    panel(
      "New calibration run",
      "Intrinsics and distortion by Zhang's method from several views of a planar pattern",
      cameras.length
        ? startForm(cameras, query.get("camera"))
        : infoBox(
            h(
              "span",
              null,
              "Add a camera first on the ",
              h("a", { href: "#/cameras" }, "Cameras"),
              " page.",
            ),
            "run-needs-camera",
          ),
    ),
    networkPanel(),
    panel("Runs", "Newest first", runsBody),
  );
}

/** A per-camera error against the twin's truth, marked when it misses the target. */
function errorCell(value, target, digits, testid) {
  const ok = Math.abs(value) < target;
  return h(
    "td",
    { class: `num ${ok ? "" : "bad-value"}`, testid, "data-value": value },
    fmt(value, digits),
    ok ? null : h("span", { class: "badge bad", style: { marginLeft: "6px" } }, "over"),
  );
}

/**
 * A line plot (uPlot) of the worst camera's error against the drive's length (simulated
 * seconds), one colour per pixel noise: solid with dots the measured error, dashed its
 * Cramer-Rao bound, and the target. `pick(cameraEntry)` returns [error, bound] in the plotted
 * unit.
 */
function accuracyPlot(rows, pick, { title, unit, target, testid }) {
  const box = h("div", { class: "accuracy-plot", testid, "data-rows": rows.length });
  const sigmas = [...new Set(rows.map((r) => r.sigma_px))].sort((a, b) => a - b);
  const xs = [...new Set(rows.map((r) => r.drive_s))].sort((a, b) => a - b);
  const worst = (r, k) =>
    Math.max(...r.cameras.map((c) => pick(c)[k]).filter((v) => Number.isFinite(v)), 0);
  const at = (sg, k) =>
    xs.map((x) => {
      const row = rows.find((r) => r.sigma_px === sg && r.drive_s === x);
      return row ? worst(row, k) : null;
    });
  const series = [];
  const data = [xs];
  sigmas.forEach((sg, i) => {
    const colour = `series-${(i % 5) + 1}`;
    series.push({ label: `σ ${sg} px`, colour, width: 2, points: true });
    data.push(at(sg, 0));
    series.push({ label: `bound, σ ${sg} px`, colour, width: 2, dash: [5, 4], points: false });
    data.push(at(sg, 1));
  });
  if (target) {
    series.push({ label: `target ${target} ${unit}`, colour: "target", width: 1.5, dash: [5, 4], points: false });
    data.push(xs.map(() => target));
  }
  // Drawn once the box is laid out, at its width.
  requestAnimationFrame(() =>
    lineChart(box, { title, x: "drive (s)", y: `worst camera (${unit})`, series, data, height: 280, fromZero: true }).catch(
      (err) => mount(box, h("p", { class: "small badge bad" }, err.message)),
    ),
  );
  return box;
}

function accuracyView(r) {
  const rows = r.accuracy || [];
  if (!rows.length) return null;
  const e = (c, key) => [c.errors?.[key], c.bound?.[key]];
  return panel(
    "Accuracy against drive length and pixel noise",
    "For this seed: drives of increasing length, the marker's true projections with Gaussian " +
      "pixel noise, calibrated and scored against the twin; solid the worst camera's error, " +
      "dashed its Cramer-Rao bound. Absolute: in the world frame the robot's start pose " +
      "defines (limited by the odometry's heading drift); aligned: the network's own geometry.",
    h(
      "div",
      { class: "plots", testid: "network-accuracy" },
      accuracyPlot(rows, (c) => e(c, "position_m").map((v) => 100 * v), {
        title: "Position error, absolute",
        unit: "cm",
        target: NETWORK_TARGETS.position_cm,
        testid: "accuracy-position",
      }),
      accuracyPlot(rows, (c) => e(c, "rotation_deg"), {
        title: "Rotation error, absolute",
        unit: "°",
        target: NETWORK_TARGETS.rotation_deg,
        testid: "accuracy-rotation",
      }),
      accuracyPlot(rows, (c) => e(c, "aligned_position_m").map((v) => 100 * v), {
        title: "Position error, aligned",
        unit: "cm",
        target: NETWORK_TARGETS.position_cm,
        testid: "accuracy-aligned-position",
      }),
      accuracyPlot(rows, (c) => e(c, "aligned_rotation_deg"), {
        title: "Rotation error, aligned",
        unit: "°",
        target: NETWORK_TARGETS.rotation_deg,
        testid: "accuracy-aligned-rotation",
      }),
    ),
  );
}

function networkResultView(run) {
  const r = run.result;
  const cams = r.cameras || [];
  const rows = cams.map((c, i) => {
    const e = c.errors || {};
    const f = c.K ? (c.K[0][0] + c.K[1][1]) / 2 : null;
    const pos = c.T_world_camera ? c.T_world_camera.slice(0, 3).map((row) => row[3]) : null;
    return h(
      "tr",
      { testid: `network-row-${i}`, "data-camera": c.name },
      h("td", null, c.camera_id ? h("a", { href: `#/cameras/${c.camera_id}` }, c.name) : c.name),
      h("td", { class: "num" }, c.poses_seen ?? "–"),
      h("td", { class: "num" }, fmt(f, 2)),
      h(
        "td",
        { class: "num" },
        pos ? pos.map((v) => fmt(v, 3)).join(", ") : "–",
      ),
      h("td", { class: "num" }, fmt(c.rms, 3)),
      e.focal_pct !== undefined
        ? errorCell(e.focal_pct, NETWORK_TARGETS.focal_pct, 3, `network-focal-${i}`)
        : h("td", { class: "num" }, "–"),
      e.position_m !== undefined
        ? errorCell(e.position_m * 100, NETWORK_TARGETS.position_cm, 2, `network-position-${i}`)
        : h("td", { class: "num" }, "–"),
      e.rotation_deg !== undefined
        ? errorCell(e.rotation_deg, NETWORK_TARGETS.rotation_deg, 3, `network-rotation-${i}`)
        : h("td", { class: "num" }, "–"),
      h("td", { class: "num", testid: `network-start-frame-${i}` },
        e.start_frame_position_m != null
          ? `${fmt(e.start_frame_position_m * 100, 2)} cm, ${fmt(e.start_frame_rotation_deg, 3)}°`
          : "–"),
      h("td", { class: "num", testid: `network-aligned-${i}` },
        e.aligned_position_m != null
          ? `${fmt(e.aligned_position_m * 100, 2)} cm, ${fmt(e.aligned_rotation_deg, 3)}°`
          : "–"),
      h("td", { class: "num", testid: `network-bound-${i}` },
        c.bound
          ? `${fmt(c.bound.position_m * 100, 2)} cm, ${fmt(c.bound.rotation_deg, 3)}° ` +
              `(aligned ${fmt(c.bound.aligned_position_m * 100, 2)} cm, ` +
              `${fmt(c.bound.aligned_rotation_deg, 3)}°)`
          : "–"),
    );
  });
  const rejected = r.rejected || [];
  const reg = r.registration;
  const registration = reg
    ? reg.theta_deg != null
      ? ` Registered to the world by ${reg.sightings} of ${reg.signposts_read} signposts read: ` +
        `turned ${fmt(reg.theta_deg, 3)}° ± ${fmt(reg.theta_std_deg, 3)}° and moved ` +
        `${reg.t_m.map((v) => fmt(v * 100, 1)).join(", ")} cm from the start pose's frame.`
      : ` Not registered to the world: ${reg.reason}.`
    : "";
  return panel(
    "Cameras calibrated",
    `${cams.length} cameras from ${r.poses ?? "–"} marker positions` +
      (r.drive_s != null ? ` over a ${fmt(r.drive_s, 0)} s drive` : "") +
      (r.sigma_px != null ? `, detections within ${fmt(r.sigma_px, 3)} px RMS of the truth` : "") +
      (r.rms_px != null
        ? `; reprojection RMS ${fmt(r.rms_px, 3)} px over all detections ` +
          `(${fmt(r.rms_whitened, 2)} standard deviations)`
        : "") +
      (r.intrinsics_from ? `. Intrinsics: ${r.intrinsics_from}` : "") +
      "." + registration +
      " Errors against the digital twin's truth (absolute: in the world, registered by the " +
      "signposts when it was; start frame: in the frame of the robot's start pose; aligned: " +
      "after the best floor alignment), beside their Cramer-Rao bound (in the start pose's " +
      "frame); targets: focal < 1 %, position < 2 cm, rotation < 0.3°.",
    h(
      "div",
      { class: "table-wrap" },
      h(
        "table",
        { testid: "network-results" },
        h(
          "thead",
          null,
          h(
            "tr",
            null,
            [
              "Camera",
              "Poses seen",
              "f (px)",
              "Position (m)",
              "RMS (px)",
              "Focal error (%)",
              "Position error (cm)",
              "Rotation error (°)",
              "Start frame error",
              "Aligned error",
              "Bound",
            ].map((t, i) => h("th", { class: i ? "num" : null }, t)),
          ),
        ),
        h("tbody", null, rows),
      ),
    ),
    rejected.length
      ? h(
          "div",
          { class: "alert", role: "note", testid: "network-rejected", style: { marginTop: "12px" } },
          h("strong", null, "Not calibrated"),
          h(
            "ul",
            null,
            rejected.map((x) => h("li", null, h("code", null, x.name), `: ${x.reason}`)),
          ),
        )
      : null,
  );
}

function resultView(run) {
  const r = run.result;
  const perView = r.per_view_rms || [];
  const labels = r.views_used ? r.views_used.map((i) => `View ${i + 1}`) : undefined;
  return h(
    "div",
    { class: perView.length ? "grid two" : "grid" },
    panel(
      "Estimated intrinsics",
      `K and distortion, ± one standard deviation (Gauss–Newton covariance)`,
      h(
        "div",
        { class: "grid two", style: { gap: "16px" } },
        h(
          "div",
          null,
          h("h3", { style: { marginBottom: "8px" } }, "K (pixels)"),
          matrixTable(r.K, 3, "run-K"),
        ),
        intrinsicsFacts(r.K, r.dist, r.std_intrinsics, "run"),
      ),
    ),
    perView.length
      ? panel(
          "Residuals per view",
          `RMS reprojection error of each view; dashed: overall ${fmt(r.rms, 4)} px`,
          barChart(perView, { reference: r.rms, labels, title: "RMS reprojection error per view" }),
        )
      : null,
  );
}

/** A 4x4 pose as its rotation matrix and translation (metres), in a table. */
const poseTable = (T, testid) => matrixTable(T, 4, testid);

/** A placement run's result: the camera's pose and K from floor points, every point's
 * residual (the pairs left out included) and the standard deviations. */
function placementResultView(run) {
  const r = run.result;
  const std = r.std || {};
  return h(
    "div",
    { class: "grid two", testid: "placement-result" },
    panel(
      "Camera placed from floor points",
      `T_world_camera and K; RMS ${fmt(r.rms, 3)} px over the pairs kept` +
        (r.rejected.length ? `; left out: ${r.rejected.map((k) => `#${k + 1}`).join(", ")}` : ""),
      poseTable(r.T_world_camera, "placement-T"),
      matrixTable(r.K, 2, "placement-K"),
      h(
        "dl",
        { class: "facts" },
        h("dt", null, "Position std"),
        h("dd", { class: "num" }, `${(std.position_m || []).map((v) => fmt(v * 100, 2)).join(", ")} cm`),
        h("dt", null, "Rotation std"),
        h("dd", { class: "num" }, `${(std.rotation_deg || []).map((v) => fmt(v, 3)).join(", ")}°`),
        h("dt", null, "Focal length std"),
        h("dd", { class: "num" }, std.f_px != null ? `${fmt(std.f_px, 2)} px` : "K known"),
      ),
    ),
    panel(
      "Residual per pair",
      "Reprojection error of each clicked pair, pixels",
      barChart(r.residuals_px, { reference: r.rms, title: "Residual per pair (px)" }),
    ),
  );
}

/** A projector run's result: the mount T_world_projector, its spread and its twin errors. */
function projectorResultView(run) {
  const r = run.result;
  const e = r.twin_errors || {};
  const fact = (label, value, testid) => [
    h("dt", null, label),
    h("dd", { class: "num", testid }, value),
  ];
  return h(
    "div",
    { class: "grid two", testid: "projector-result" },
    panel(
      "Projector mount",
      `T_world_projector from ${r.spots} spots (${r.spots_from}), located by ` +
        `${(r.cameras || []).join(", ") || "–"}; ± one standard deviation`,
      poseTable(r.T_world_projector, "projector-T"),
      h(
        "dl",
        { class: "facts" },
        fact("Spots", String(r.spots), "projector-spots"),
        fact("Floor RMS", `${fmt(r.rms_m * 1000, 2)} mm`, "projector-rms"),
        fact("Position std", `${fmt(r.position_std_m * 1000, 2)} mm`, "projector-position-std"),
        fact("Rotation std", `${fmt(r.rotation_std_deg, 3)}°`, "projector-rotation-std"),
        fact("Tilt offset", `${fmt((r.tilt_offset_rad * 180) / Math.PI, 3)}°`, "projector-tilt"),
      ),
    ),
    panel(
      "Against the digital twin",
      "The mount's errors against the twin's true projector (aligned: after removing the frame " +
        "error of the cameras' own calibration); targets: position < 1 cm, rotation < 0.2°.",
      h(
        "dl",
        { class: "facts", testid: "projector-twin-errors" },
        fact("Position error", `${fmt(e.position_m * 1000, 2)} mm`, "projector-position-error"),
        fact("Rotation error", `${fmt(e.rotation_deg, 3)}°`, "projector-rotation-error"),
        fact(
          "Aligned",
          `${fmt(e.aligned_position_m * 1000, 2)} mm, ${fmt(e.aligned_rotation_deg, 3)}°`,
          "projector-aligned-error",
        ),
        fact("Tilt offset error", `${fmt((e.tilt_offset_rad * 180) / Math.PI, 3)}°`),
        fact("Located spots", `${fmt(r.spot_error_rms_m * 1000, 2)} mm RMS per axis`),
      ),
    ),
  );
}

/** A hand-eye run's result: X = T_ee_camera, its standard deviations, the residuals and, on
 * the twin, every method's errors against the truth. */
function handEyeResultView(run) {
  const r = run.result;
  const fact = (label, value, testid) => [
    h("dt", null, label),
    h("dd", { class: "num", testid }, value),
  ];
  const methods = r.methods || [];
  const row = (m, testid) =>
    h(
      "tr",
      { testid },
      h("td", null, m.method),
      h("td", { class: "num" }, fmt(m.rotation_error_deg, 4)),
      h("td", { class: "num" }, fmt(m.translation_error_mm, 3)),
      h("td", { class: "num" }, fmt(m.rotation_std_deg, 4)),
      h("td", { class: "num" }, fmt(m.translation_std_mm, 3)),
    );
  return h(
    "div",
    { class: "grid two", testid: "run-hand-eye-result" },
    panel(
      "Hand-eye transform",
      `X = T_ee_camera (${r.method}) from ${r.views} views, ${r.motions} motions; ` +
        "± one standard deviation",
      poseTable(r.X, "run-hand-eye-X"),
      h(
        "dl",
        { class: "facts" },
        fact("Rotation std", `${fmt(r.rotation_std_deg, 4)}°`, "run-hand-eye-rotation-std"),
        fact(
          "Translation std",
          `${fmt(r.translation_std_m * 1000, 3)} mm`,
          "run-hand-eye-translation-std",
        ),
        fact("Refined", r.refined ? `yes, ${fmt(r.rms_px, 3)} px RMS` : "no", "run-hand-eye-refined"),
        r.sigma_px != null ? fact("Pixel noise (twin)", `${fmt(r.sigma_px, 2)} px`) : null,
      ),
    ),
    (r.rotation_residuals_deg || []).length
      ? panel(
          "Residuals per motion",
          "Rotation residual of each motion pair (AX = XB), degrees",
          barChart(r.rotation_residuals_deg, {
            unit: "°",
            title: "Rotation residual per motion",
          }),
        )
      : null,
    r.truth
      ? panel(
          "Against the digital twin",
          "This result and every linear method on the same views, against the twin's true " +
            "hand-eye; targets: rotation < 0.1°, translation < 1 mm.",
          h(
            "div",
            { class: "table-wrap" },
            h(
              "table",
              { testid: "run-hand-eye-methods" },
              h(
                "thead",
                null,
                h(
                  "tr",
                  null,
                  [
                    "Method",
                    "Rotation error (°)",
                    "Translation error (mm)",
                    "Rotation std (°)",
                    "Translation std (mm)",
                  ].map((t, i) => h("th", { class: i ? "num" : null }, t)),
                ),
              ),
              h(
                "tbody",
                null,
                row(r.truth, "run-hand-eye-truth"),
                methods.map((m, i) => row(m, `run-hand-eye-method-${i}`)),
              ),
            ),
          ),
        )
      : null,
  );
}

/** What the Apply button of a succeeded run says, by kind. */
function applyLabel(run) {
  if (run.kind === "network") return "Apply to the cameras";
  if (run.kind === "projector") return `Apply to projector #${run.result.projector_id}`;
  if (run.kind === "hand-eye") return `Apply to arm #${run.result.arm_id}`;
  return "Apply to camera";
}

/** Whether a succeeded run has something to apply to. */
const applicable = (run) =>
  Boolean(run.camera_id) || ["network", "projector", "hand-eye"].includes(run.kind);

export async function renderRun(main, [id], _query, setTitle) {
  setTitle(`Calibration run #${id}`);
  let applied = false;
  const header = h("div");
  const body = h("div", { class: "grid" });
  const notice = h("div", { "aria-live": "assertive" });
  mount(main, header, notice, body);

  const applyButton = (run) =>
    h(
      "button",
      {
        class: "btn primary",
        type: "button",
        testid: "run-apply",
        disabled: applied,
        onClick: async (ev) => {
          const btn = ev.currentTarget;
          btn.disabled = true;
          mount(notice);
          try {
            const answer = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
            applied = true;
            btn.textContent = "Applied";
            if (run.kind === "projector" || run.kind === "hand-eye") {
              const what = run.kind === "projector" ? "projector" : "arm";
              const target = run.kind === "projector" ? "#/navigation" : "#/manipulation";
              toast(`Calibration applied to ${what} ${answer.name ?? `#${answer.id}`}`);
              mount(
                notice,
                h(
                  "div",
                  { class: "alert info", role: "status", testid: "run-applied" },
                  run.kind === "projector"
                    ? `Applied: projector ${answer.name} now has this mount (recorded in its ` +
                        "calibration history). "
                    : `Applied: arm ${answer.name} now has this hand-eye transform (recorded ` +
                        "in its hand-eye history). ",
                  h(
                    "a",
                    { href: target, testid: "run-target-link" },
                    run.kind === "projector" ? "Plan a path with it" : "Open Manipulation",
                  ),
                  ".",
                ),
              );
              return;
            }
            if (run.kind === "network") {
              const n = Array.isArray(answer) ? answer.length : 0;
              toast(`Network calibration applied to ${n} cameras`);
              mount(
                notice,
                h(
                  "div",
                  { class: "alert info", role: "status", testid: "run-applied" },
                  `Applied to ${n} cameras: their intrinsics and poses now come from this run. `,
                  h("a", { href: "#/cameras", testid: "run-camera-link" }, "Open the cameras"),
                  ".",
                ),
              );
              return;
            }
            toast(`Calibration applied to camera #${run.camera_id}`);
            mount(
              notice,
              h(
                "div",
                { class: "alert info", role: "status", testid: "run-applied" },
                "Applied. ",
                h(
                  "a",
                  { href: `#/cameras/${run.camera_id}`, testid: "run-camera-link" },
                  "Open the camera",
                ),
                " to see its new intrinsics.",
              ),
            );
          } catch (err) {
            btn.disabled = false;
            mount(notice, errorBox(err, "run-apply-error"));
          }
        },
      },
      applied ? "Applied" : applyLabel(run),
    );

  const draw = (run) => {
    const facts = h(
      "dl",
      { class: "facts", testid: "run-facts" },
      h("dt", null, "Status"),
      h("dd", null, statusBadge(run.status, "run-status")),
      h("dt", null, "Camera"),
      h(
        "dd",
        null,
        run.camera_id
          ? h("a", { href: `#/cameras/${run.camera_id}` }, cameraName || `#${run.camera_id}`)
          : run.kind === "network"
            ? "every camera of the digital twin's home"
            : run.kind === "projector" && run.result
              ? `locating the spots: ${(run.result.cameras || []).join(", ")}`
              : "–",
      ),
      run.kind === "hand-eye" && run.arm_id
        ? [h("dt", null, "Arm"), h("dd", { testid: "run-arm" }, `#${run.arm_id}`)]
        : null,
      run.kind === "projector" && run.result
        ? [
            h("dt", null, "Projector"),
            h("dd", { testid: "run-projector" }, `#${run.result.projector_id}`),
          ]
        : null,
      h("dt", null, "Kind"),
      h("dd", null, [run.kind, run.source ? ` · ${run.source}` : ""]),
      h("dt", null, "Options"),
      h(
        "dd",
        { class: "mono small" },
        run.options
          ? Object.entries(run.options)
              .map(([k, v]) => `${k}=${v}`)
              .join(", ")
          : "–",
      ),
      h("dt", null, "Created"),
      h("dd", null, when(run.created_at)),
      h("dt", null, "Ran for"),
      h("dd", null, duration(run.started_at, run.finished_at)),
      run.result && run.kind === "projector"
        ? [
            h("dt", null, "RMS error"),
            h(
              "dd",
              { class: "num", testid: "run-rms" },
              `${fmt(run.result.rms_m * 1000, 2)} mm over ${run.result.spots} spots`,
            ),
          ]
        : null,
      run.result && run.kind === "hand-eye"
        ? [
            h("dt", null, "Uncertainty"),
            h(
              "dd",
              { class: "num", testid: "run-rms" },
              `${fmt(run.result.rotation_std_deg, 4)}°, ` +
                `${fmt(run.result.translation_std_m * 1000, 3)} mm (one std)`,
            ),
          ]
        : null,
      run.result && run.kind !== "projector" && run.kind !== "hand-eye"
        ? [
            h("dt", null, "RMS error"),
            h(
              "dd",
              { class: "num", testid: "run-rms" },
              `${fmt(run.result.rms ?? run.result.rms_px, 4)} px` +
                (run.result.per_view_rms
                  ? ` over ${run.result.per_view_rms.length} views`
                  : run.result.cameras
                    ? ` over ${run.result.cameras.length} cameras`
                    : ""),
            ),
          ]
        : null,
    );
    mount(
      header,
      panel(
        null,
        null,
        h(
          "div",
          { class: "panel-head", style: { marginBottom: 0 } },
          facts,
          h(
            "div",
            { class: "form-actions", style: { marginTop: 0 } },
            run.status === "succeeded" && run.result && applicable(run)
              ? applyButton(run)
              : null,
            h("a", { class: "btn", href: "#/calibration" }, "All runs"),
          ),
        ),
      ),
    );
    if (run.status === "succeeded" && run.result && run.kind === "network")
      mount(body, networkResultView(run), accuracyView(run.result));
    else if (run.status === "succeeded" && run.result && run.kind === "projector")
      mount(body, projectorResultView(run));
    else if (run.status === "succeeded" && run.result && run.kind === "hand-eye")
      mount(body, handEyeResultView(run));
    else if (run.status === "succeeded" && run.result && run.kind === "placement")
      mount(body, placementResultView(run));
    else if (run.status === "succeeded" && run.result?.K) mount(body, resultView(run));
    else if (run.status === "failed" || run.status === "interrupted")
      mount(
        body,
        errorBox(
          { title: `The run ${run.status}`, detail: run.error || "No reason was recorded." },
          "run-error",
        ),
      );
    else mount(body, progressView(run));
  };

  // A queued or running run: its stage and a bar of the fraction done, as its worker reports.
  const progressView = (run) => {
    const p = run.progress;
    const pct = p ? Math.round(100 * p.fraction) : 0;
    const retry = run.attempts > 1 ? ` (attempt ${run.attempts}: an earlier worker stopped)` : "";
    return h(
      "div",
      { role: "status", testid: "run-waiting" },
      h("p", { class: "muted" }, `The run is ${run.status}${retry}; this page updates by itself.`),
      run.status === "running" && p
        ? h(
            "label",
            { testid: "run-progress" },
            `${p.stage}: ${pct} %`,
            h("progress", {
              max: 100,
              value: pct,
              style: { display: "block", width: "100%", height: "0.75rem", marginTop: "0.25rem" },
            }),
          )
        : null,
    );
  };

  let cameraName = null;
  const nameCamera = async (run) => {
    if (cameraName !== null || !run.camera_id) return;
    cameraName = await api(`/cameras/${run.camera_id}`).then(
      (c) => c.name,
      () => `#${run.camera_id}`, // a deleted camera: the run keeps its id
    );
  };
  // GET the run until it ends; keep trying while the service is unreachable or restarting,
  // stop on a refusal (4xx), which will not change. The page is ready once the first answer
  // is drawn.
  let firstDrawn;
  const drawn = new Promise((resolve) => {
    firstDrawn = resolve;
  });
  const reads = poll(() => api(`/calibration-runs/${id}`), {
    interval: POLL_MS,
    stopOn4xx: true,
    onValue: async (run) => {
      await nameCamera(run);
      draw(run);
      firstDrawn();
      return !TERMINAL.has(run.status);
    },
    onError: (err) => {
      mount(notice, errorBox(err, "run-poll-error"));
      firstDrawn();
    },
  });
  await drawn;
  return () => reads.stop();
}
