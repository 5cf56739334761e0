// Hand-eye calibration of an arm's eye-in-hand camera: a run on the twin, followed until it
// ends, its result against the twin's truth and the linear methods on the same views, applied
// to the arm.

import { api } from "../../api.js";
import { actionButton, formRow, sending } from "../../forms.js";
import {
  errorBox,
  facts,
  fmt,
  h,
  matrixTable,
  mount,
  panel,
  sig,
  statusBadge,
  table,
  toast,
} from "../../ui.js";
import { armSelect } from "./arms.js";
import { follow, progressLine, TERMINAL } from "./follow.js";

/** The run's figures: method, views, standard deviations, RMS and, on the twin, its errors. */
function handEyeFacts(r) {
  const rows = [
    ["Method", r.method],
    ["Views (motions)", `${r.views} (${r.motions})`],
    ["σ rotation", `${sig(r.rotation_std_deg, 3)}°`],
    ["σ translation", `${sig(r.translation_std_m * 1000, 3)} mm`],
    ["Reprojection RMS", r.rms_px === null ? "–" : `${fmt(r.rms_px, 3)} px`],
  ];
  if (r.truth) {
    rows.push(["Error vs the twin: rotation", `${sig(r.truth.rotation_error_deg, 3)}°`]);
    rows.push(["Error vs the twin: translation", `${sig(r.truth.translation_error_mm, 3)} mm`]);
  }
  return facts(null, rows);
}

/** The linear methods' errors on the same views, or null when the run gave none. */
function methodsTable(methods) {
  if (!methods?.length) return null;
  const head = ["Linear method, same views", "Rotation error", "Translation error"];
  const row = (m) =>
    h(
      "tr",
      null,
      h("td", null, m.method),
      h("td", { class: "num" }, `${sig(m.rotation_error_deg, 3)}°`),
      h("td", { class: "num" }, `${sig(m.translation_error_mm, 3)} mm`),
    );
  return h(
    "div",
    { class: "table-wrap" },
    table({ testid: "hand-eye-methods" }, head, methods.map(row)),
  );
}

function handEyeResult(run, onApplied) {
  const apply = actionButton(
    { class: "btn primary", testid: "hand-eye-apply" },
    "Apply to the arm",
    async () => {
      const arm = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
      toast(`Hand-eye transform applied to arm #${arm.id}`);
      await onApplied();
    },
  );
  return h(
    "div",
    { testid: "hand-eye-result" },
    handEyeFacts(run.result),
    h("h3", null, "X = T_ee_camera"),
    matrixTable(run.result.X, 4, "hand-eye-X"),
    methodsTable(run.result.methods),
    h("div", { class: "form-actions" }, apply),
  );
}

/** Draw a hand-eye run in `out`: its status, then its progress, its failure or its result. */
function drawRun(out, run, onApplied) {
  const head = h("p", null, `Run #${run.id}`, " ", statusBadge(run.status, "hand-eye-status"));
  if (run.status === "succeeded") mount(out, head, handEyeResult(run, onApplied));
  else if (TERMINAL.has(run.status))
    mount(
      out,
      head,
      errorBox({ title: `The run ${run.status}`, detail: run.error || "" }, "hand-eye-error"),
    );
  else
    mount(out, head, run.progress ? progressLine(run.progress.stage, run.progress.fraction) : null);
}

/** The run's settings: the arm, the method, the views, rendered or not, the seed. */
function handEyeFields(arms) {
  const arm = armSelect("hand-eye-arm", arms);
  const method = h(
    "select",
    { id: "hand-eye-method", testid: "hand-eye-method" },
    ["park", "tsai", "daniilidis", "andreff", "two-group"].map((m) => h("option", { value: m }, m)),
  );
  const views = h("input", {
    id: "hand-eye-views",
    testid: "hand-eye-views",
    type: "number",
    min: 3,
    max: 60,
    value: "15",
  });
  const rendered = h("input", {
    id: "hand-eye-rendered",
    testid: "hand-eye-rendered",
    type: "checkbox",
    checked: true,
  });
  const seed = h("input", {
    id: "hand-eye-seed",
    testid: "hand-eye-seed",
    type: "number",
    min: 0,
    step: 1,
    placeholder: "random",
  });
  return {
    rows: [
      formRow("hand-eye-arm", "Arm", arm),
      formRow("hand-eye-method", "Method", method),
      formRow("hand-eye-views", "Views", views),
      formRow("hand-eye-rendered", "Rendered images (about 1 s a view)", rendered),
      formRow("hand-eye-seed", "Seed (views)", seed),
    ],
    body: () => ({
      kind: "hand-eye",
      arm_id: Number(arm.value),
      method: method.value,
      twin: {
        views: Number(views.value),
        rendered: rendered.checked,
        seed: seed.value === "" ? null : Number(seed.value),
      },
    }),
  };
}

export function handEyePanel(arms, stops, onApplied) {
  const out = h("div", { class: "manip-out", "aria-live": "polite" });
  const fields = handEyeFields(arms);
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "hand-eye-start", disabled: !arms.length },
    "Calibrate on the twin",
  );
  const start = async () => {
    const run = await api("/calibration-runs", { method: "POST", json: fields.body() });
    stops.handEye?.();
    stops.handEye = follow(`/calibration-runs/${run.id}`, (r) => drawRun(out, r, onApplied));
  };
  const form = h(
    "form",
    {
      class: "form-grid",
      testid: "hand-eye-form",
      onSubmit: sending(submit, start, { errors: out, testid: "hand-eye-error", keep: true }),
    },
    fields.rows,
    h("div", { class: "form-actions" }, submit),
  );
  return panel(
    "Hand-eye calibration",
    "The twin's arm shows its eye-in-hand camera a chessboard on the dining table from many " +
      "poses; X = T_ee_camera is solved linearly, then refined by reprojection error. Your " +
      'own arm\'s pose pairs: POST /api/v1/calibration-runs with source "poses"',
    form,
    out,
  );
}
