// A finished calibration run's results, one view per kind of run: a camera's intrinsics, a
// network's cameras with their errors against the twin and its accuracy against drive length
// (uPlot), a placement, a projector's mount, an arm's hand-eye transform.

import { lineChart } from "../../chart.js";
import { barChart } from "../../plot.js";
import { facts, fmt, h, matrixTable, mount, panel, table } from "../../ui.js";
import { intrinsicsFacts } from "../cameras/intrinsics.js";

// The targets the twin's errors are marked against.
const NETWORK_TARGETS = { focal_pct: 1, position_cm: 2, rotation_deg: 0.3 };

/** A row of a list of facts: `value` (a number) under `label`. */
const fact = (label, value, testid) => [label, value, { class: "num", testid }];

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
    series.push({
      label: `target ${target} ${unit}`,
      colour: "target",
      width: 1.5,
      dash: [5, 4],
      points: false,
    });
    data.push(xs.map(() => target));
  }
  // Drawn once the box is laid out, at its width.
  requestAnimationFrame(() =>
    lineChart(box, {
      title,
      x: "drive (s)",
      y: `worst camera (${unit})`,
      series,
      data,
      height: 280,
      fromZero: true,
    }).catch((err) => mount(box, h("p", { class: "small badge bad" }, err.message))),
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

/** One camera of a network run: what was fitted, its errors against the twin's truth and its
 * bound. */
function networkRow(c, i) {
  const e = c.errors || {};
  const f = c.K ? (c.K[0][0] + c.K[1][1]) / 2 : null;
  const pos = c.T_world_camera ? c.T_world_camera.slice(0, 3).map((row) => row[3]) : null;
  const error = (value, target, digits, name) =>
    value !== undefined
      ? errorCell(value, target, digits, `network-${name}-${i}`)
      : h("td", { class: "num" }, "–");
  const pair = (position, rotation) => `${fmt(position * 100, 2)} cm, ${fmt(rotation, 3)}°`;
  return h(
    "tr",
    { testid: `network-row-${i}`, "data-camera": c.name },
    h("td", null, c.camera_id ? h("a", { href: `#/cameras/${c.camera_id}` }, c.name) : c.name),
    h("td", { class: "num" }, c.poses_seen ?? "–"),
    h("td", { class: "num" }, fmt(f, 2)),
    h("td", { class: "num" }, pos ? pos.map((v) => fmt(v, 3)).join(", ") : "–"),
    h("td", { class: "num" }, fmt(c.rms, 3)),
    error(e.focal_pct, NETWORK_TARGETS.focal_pct, 3, "focal"),
    error(
      e.position_m !== undefined ? e.position_m * 100 : undefined,
      NETWORK_TARGETS.position_cm,
      2,
      "position",
    ),
    error(e.rotation_deg, NETWORK_TARGETS.rotation_deg, 3, "rotation"),
    h(
      "td",
      { class: "num", testid: `network-start-frame-${i}` },
      e.start_frame_position_m != null
        ? pair(e.start_frame_position_m, e.start_frame_rotation_deg)
        : "–",
    ),
    h(
      "td",
      { class: "num", testid: `network-aligned-${i}` },
      e.aligned_position_m != null ? pair(e.aligned_position_m, e.aligned_rotation_deg) : "–",
    ),
    h(
      "td",
      { class: "num", testid: `network-bound-${i}` },
      c.bound
        ? `${pair(c.bound.position_m, c.bound.rotation_deg)} ` +
            `(aligned ${pair(c.bound.aligned_position_m, c.bound.aligned_rotation_deg)})`
        : "–",
    ),
  );
}

/** What a network run did: cameras, marker positions, drive, noise, RMS, where the intrinsics
 * came from and how the result was registered to the world. */
function networkSummary(r) {
  const reg = r.registration;
  const registration = reg
    ? reg.theta_deg != null
      ? ` Registered to the world by ${reg.sightings} of ${reg.signposts_read} signposts read: ` +
        `turned ${fmt(reg.theta_deg, 3)}° ± ${fmt(reg.theta_std_deg, 3)}° and moved ` +
        `${reg.t_m.map((v) => fmt(v * 100, 1)).join(", ")} cm from the start pose's frame.`
      : ` Not registered to the world: ${reg.reason}.`
    : "";
  return (
    `${(r.cameras || []).length} cameras from ${r.poses ?? "–"} marker positions` +
    (r.drive_s != null ? ` over a ${fmt(r.drive_s, 0)} s drive` : "") +
    (r.sigma_px != null ? `, detections within ${fmt(r.sigma_px, 3)} px RMS of the truth` : "") +
    (r.rms_px != null
      ? `; reprojection RMS ${fmt(r.rms_px, 3)} px over all detections ` +
        `(${fmt(r.rms_whitened, 2)} standard deviations)`
      : "") +
    (r.intrinsics_from ? `. Intrinsics: ${r.intrinsics_from}` : "") +
    "." +
    registration +
    " Errors against the digital twin's truth (absolute: in the world, registered by the " +
    "signposts when it was; start frame: in the frame of the robot's start pose; aligned: " +
    "after the best floor alignment), beside their Cramer-Rao bound (in the start pose's " +
    "frame); targets: focal < 1 %, position < 2 cm, rotation < 0.3°."
  );
}

const NETWORK_COLUMNS = [
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
];

function networkResultView(run) {
  const r = run.result;
  const rejected = r.rejected || [];
  return panel(
    "Cameras calibrated",
    networkSummary(r),
    h(
      "div",
      { class: "table-wrap" },
      table(
        { testid: "network-results" },
        NETWORK_COLUMNS.map((t, i) => [t, { class: i ? "num" : null }]),
        (r.cameras || []).map(networkRow),
      ),
    ),
    rejected.length
      ? h(
          "div",
          {
            class: "alert",
            role: "note",
            testid: "network-rejected",
            style: { marginTop: "12px" },
          },
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
      facts(null, [
        fact("Position std", `${(std.position_m || []).map((v) => fmt(v * 100, 2)).join(", ")} cm`),
        fact("Rotation std", `${(std.rotation_deg || []).map((v) => fmt(v, 3)).join(", ")}°`),
        fact("Focal length std", std.f_px != null ? `${fmt(std.f_px, 2)} px` : "K known"),
      ]),
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
  return h(
    "div",
    { class: "grid two", testid: "projector-result" },
    panel(
      "Projector mount",
      `T_world_projector from ${r.spots} spots (${r.spots_from}), located by ` +
        `${(r.cameras || []).join(", ") || "–"}; ± one standard deviation`,
      poseTable(r.T_world_projector, "projector-T"),
      facts(null, [
        fact("Spots", String(r.spots), "projector-spots"),
        fact("Floor RMS", `${fmt(r.rms_m * 1000, 2)} mm`, "projector-rms"),
        fact("Position std", `${fmt(r.position_std_m * 1000, 2)} mm`, "projector-position-std"),
        fact("Rotation std", `${fmt(r.rotation_std_deg, 3)}°`, "projector-rotation-std"),
        fact("Tilt offset", `${fmt((r.tilt_offset_rad * 180) / Math.PI, 3)}°`, "projector-tilt"),
      ]),
    ),
    panel(
      "Against the digital twin",
      "The mount's errors against the twin's true projector (aligned: after removing the frame " +
        "error of the cameras' own calibration); targets: position < 1 cm, rotation < 0.2°.",
      facts({ testid: "projector-twin-errors" }, [
        fact("Position error", `${fmt(e.position_m * 1000, 2)} mm`, "projector-position-error"),
        fact("Rotation error", `${fmt(e.rotation_deg, 3)}°`, "projector-rotation-error"),
        fact(
          "Aligned",
          `${fmt(e.aligned_position_m * 1000, 2)} mm, ${fmt(e.aligned_rotation_deg, 3)}°`,
          "projector-aligned-error",
        ),
        fact("Tilt offset error", `${fmt((e.tilt_offset_rad * 180) / Math.PI, 3)}°`),
        fact("Located spots", `${fmt(r.spot_error_rms_m * 1000, 2)} mm RMS per axis`),
      ]),
    ),
  );
}

/** A hand-eye run's result: X = T_ee_camera, its standard deviations, the residuals and, on
 * the twin, every method's errors against the truth. */
function handEyeResultView(run) {
  const r = run.result;
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
      facts(null, [
        fact("Rotation std", `${fmt(r.rotation_std_deg, 4)}°`, "run-hand-eye-rotation-std"),
        fact(
          "Translation std",
          `${fmt(r.translation_std_m * 1000, 3)} mm`,
          "run-hand-eye-translation-std",
        ),
        fact(
          "Refined",
          r.refined ? `yes, ${fmt(r.rms_px, 3)} px RMS` : "no",
          "run-hand-eye-refined",
        ),
        r.sigma_px != null ? fact("Pixel noise (twin)", `${fmt(r.sigma_px, 2)} px`) : null,
      ]),
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
            table(
              { testid: "run-hand-eye-methods" },
              [
                "Method",
                "Rotation error (°)",
                "Translation error (mm)",
                "Rotation std (°)",
                "Translation std (mm)",
              ].map((t, i) => [t, { class: i ? "num" : null }]),
              [
                row(r.truth, "run-hand-eye-truth"),
                methods.map((m, i) => row(m, `run-hand-eye-method-${i}`)),
              ],
            ),
          ),
        )
      : null,
  );
}

/** Return the views of a succeeded run's result, by its kind; null when it has none. */
export function resultViews(run) {
  if (run.kind === "network") return [networkResultView(run), accuracyView(run.result)];
  if (run.kind === "projector") return [projectorResultView(run)];
  if (run.kind === "hand-eye") return [handEyeResultView(run)];
  if (run.kind === "placement") return [placementResultView(run)];
  if (run.result.K) return [resultView(run)];
  return null;
}
