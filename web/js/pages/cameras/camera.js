// One camera's page: its live image and health, what it is, its intrinsics and pose, the panel
// that places it on the plan, the residuals of its calibration and its calibration history.

import { api, download, settled, spaceById } from "../../api.js";
import { barChart } from "../../plot.js";
import {
  badge,
  errorBox,
  facts,
  fmt,
  h,
  matrixTable,
  mount,
  panel,
  table,
  toast,
  toastError,
  when,
} from "../../ui.js";
import { cameraStatus } from "../cameras.js";
import { healthView } from "./health.js";
import { intrinsicsFacts } from "./intrinsics.js";
import { liveView } from "./live.js";
import { placePanel } from "./placement.js";

/** The link to calibration run `id`, shown as `text`. */
const runLink = (id, text) => h("a", { href: `#/calibration/runs/${id}` }, text);

function spaceName(spaceId) {
  if (spaceId === null || spaceId === undefined) return "none";
  return spaceById(spaceId)?.name || `space ${spaceId}`;
}

/** The camera's buttons: calibrate it, export its calibration (OpenCV, ROS), delete it. */
function cameraActions(cam) {
  const exportButton = (format, label) =>
    h(
      "button",
      {
        class: "btn",
        type: "button",
        testid: `export-${format}`,
        disabled: !cam.K,
        title: cam.K ? null : "Calibrate the camera first",
        onClick: () =>
          download(
            `/cameras/${cam.id}/calibration.yaml?format=${format}`,
            `${cam.name}-${format}.yaml`,
          ).catch(toastError),
      },
      label,
    );
  const remove = async () => {
    if (!confirm(`Delete camera “${cam.name}” and its calibration history?`)) return;
    try {
      await api(`/cameras/${cam.id}`, { method: "DELETE" });
      toast(`Camera “${cam.name}” deleted`);
      location.hash = "#/cameras";
    } catch (err) {
      toastError(err);
    }
  };
  return h(
    "div",
    { class: "form-actions" },
    h(
      "a",
      { class: "btn primary", href: `#/calibration?camera=${cam.id}`, testid: "calibrate-camera" },
      "Calibrate…",
    ),
    exportButton("opencv", "Export OpenCV YAML"),
    exportButton("ros", "Export ROS camera_info"),
    h(
      "button",
      { class: "btn danger", type: "button", testid: "delete-camera", onClick: remove },
      "Delete",
    ),
  );
}

/** What the camera is: status, space, image size, the run that calibrated it, dates. */
function detailsPanel(cam) {
  const rows = [
    ["Status", badge(cameraStatus(cam))],
    ["Space", spaceName(cam.space_id), { testid: "camera-space" }],
    ["Image size", `${cam.width} × ${cam.height} px`, { class: "num" }],
    [
      "Calibrated by",
      cam.calibration_run_id
        ? runLink(cam.calibration_run_id, `run #${cam.calibration_run_id}`)
        : "–",
    ],
    ["Created", when(cam.created_at)],
    ["Updated", when(cam.updated_at)],
  ];
  return panel("Camera", null, facts({ testid: "camera-facts" }, rows), cameraActions(cam));
}

/** K and the distortion with the standard deviations of the run that set them (`runRead`:
 * {value} or {error}). */
function intrinsicsPanel(cam, runRead) {
  const run = runRead.value;
  return panel(
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
          intrinsicsFacts(cam.K, cam.dist, run?.result?.std_intrinsics, "camera"),
          runRead.error ? errorBox(runRead.error, "camera-run-error") : null,
        )
      : h(
          "p",
          { class: "empty", testid: "camera-uncalibrated" },
          "Not calibrated yet. Start a calibration run to estimate K and the distortion.",
        ),
  );
}

function posePanel(cam) {
  return panel(
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
}

/** The RMS reprojection error per view of the run that set the calibration, or null. */
function residualsPanel(run) {
  if (!run?.result?.per_view_rms?.length) return null;
  return panel(
    "Residuals of the applied calibration",
    `Run #${run.id}: RMS reprojection error per view`,
    barChart(run.result.per_view_rms, {
      reference: run.result.rms,
      title: "RMS reprojection error per view",
    }),
  );
}

/** Every calibration applied to the camera (`historyRead`: {value} or {error}), newest first. */
function historyPanel(historyRead) {
  let body;
  if (historyRead.error) {
    body = errorBox(historyRead.error, "history-error");
  } else {
    const rows = Array.isArray(historyRead.value)
      ? historyRead.value
      : historyRead.value.items || [];
    body = rows.length
      ? h("div", { class: "table-wrap" }, historyTable(rows))
      : h(
          "p",
          { class: "empty", testid: "calibration-history-empty" },
          "No calibration applied yet.",
        );
  }
  return panel(
    "Calibration history",
    "Every calibration applied to this camera, newest first",
    body,
  );
}

function historyTable(rows) {
  const head = ["Applied", "Run", "fx", "fy", "cx", "cy", "RMS (px)"];
  const row = (c) =>
    h(
      "tr",
      null,
      h("td", { class: "small" }, when(c.created_at)),
      h(
        "td",
        null,
        c.calibration_run_id ? runLink(c.calibration_run_id, `#${c.calibration_run_id}`) : "–",
      ),
      [c.K[0][0], c.K[1][1], c.K[0][2], c.K[1][2]].map((v) => h("td", { class: "num" }, fmt(v, 2))),
      h("td", { class: "num" }, fmt(c.rms, 4)),
    );
  const columns = head.map((t, i) => [t, { class: i >= 2 ? "num" : null }]);
  return table({ testid: "calibration-history" }, columns, rows.map(row));
}

export async function renderCamera(main, [id], _query, setTitle) {
  const cam = await api(`/cameras/${id}`);
  setTitle(cam.name);
  const [historyRead, runRead] = await Promise.all([
    settled(api(`/cameras/${id}/calibrations`)),
    // The run that set the calibration; a failure is reported next to the intrinsics.
    cam.calibration_run_id ? settled(api(`/calibration-runs/${cam.calibration_run_id}`)) : {},
  ]);
  const live = liveView(id);
  const health = healthView(id, cam.health);
  const place = await placePanel(cam, () => location.reload());
  mount(
    main,
    h(
      "div",
      { class: "grid wide-left", style: { alignItems: "start" } },
      live.panel,
      h("div", { class: "grid" }, health.panel, detailsPanel(cam)),
    ),
    h("div", { class: "grid wide-left" }, intrinsicsPanel(cam, runRead), posePanel(cam)),
    place,
    residualsPanel(runRead.value),
    historyPanel(historyRead),
  );
  return () => {
    live.stop();
    health.stop();
  };
}
