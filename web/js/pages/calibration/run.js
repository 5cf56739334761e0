// A calibration run's page: its facts, its progress while it runs (read again until it ends),
// its results once it succeeded (calibration/results.js) and the button that applies them.

import { api, poll } from "../../api.js";
import {
  duration,
  errorBox,
  facts,
  fmt,
  h,
  mount,
  panel,
  statusBadge,
  toast,
  when,
} from "../../ui.js";
import { resultViews } from "./results.js";

const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);
const POLL_MS = 600;

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

/** Toast what a run was applied to (the service's answer to POST .../apply) and return the
 * notice that links to where it now shows. */
function appliedNotice(run, answer) {
  if (run.kind === "projector" || run.kind === "hand-eye") {
    const what = run.kind === "projector" ? "projector" : "arm";
    const target = run.kind === "projector" ? "#/navigation" : "#/manipulation";
    toast(`Calibration applied to ${what} ${answer.name ?? `#${answer.id}`}`);
    return h(
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
    );
  }
  if (run.kind === "network") {
    const n = Array.isArray(answer) ? answer.length : 0;
    toast(`Network calibration applied to ${n} cameras`);
    return h(
      "div",
      { class: "alert info", role: "status", testid: "run-applied" },
      `Applied to ${n} cameras: their intrinsics and poses now come from this run. `,
      h("a", { href: "#/cameras", testid: "run-camera-link" }, "Open the cameras"),
      ".",
    );
  }
  toast(`Calibration applied to camera #${run.camera_id}`);
  return h(
    "div",
    { class: "alert info", role: "status", testid: "run-applied" },
    "Applied. ",
    h("a", { href: `#/cameras/${run.camera_id}`, testid: "run-camera-link" }, "Open the camera"),
    " to see its new intrinsics.",
  );
}

// A queued or running run: its stage and a bar of the fraction done, as its worker reports.
function progressView(run) {
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
}

/** What the run's camera is: a link to it, or what a run of no camera looked through. */
function runCamera(run, cameraName) {
  if (run.camera_id)
    return h("a", { href: `#/cameras/${run.camera_id}` }, cameraName || `#${run.camera_id}`);
  if (run.kind === "network") return "every camera of the digital twin's home";
  if (run.kind === "projector" && run.result)
    return `locating the spots: ${(run.result.cameras || []).join(", ")}`;
  return "–";
}

/** The run's error measure, [label, value], by its kind; null before it has a result. */
function runError(run) {
  const r = run.result;
  if (!r) return null;
  if (run.kind === "projector")
    return ["RMS error", `${fmt(r.rms_m * 1000, 2)} mm over ${r.spots} spots`];
  if (run.kind === "hand-eye")
    return [
      "Uncertainty",
      `${fmt(r.rotation_std_deg, 4)}°, ${fmt(r.translation_std_m * 1000, 3)} mm (one std)`,
    ];
  const over = r.per_view_rms
    ? ` over ${r.per_view_rms.length} views`
    : r.cameras
      ? ` over ${r.cameras.length} cameras`
      : "";
  return ["RMS error", `${fmt(r.rms ?? r.rms_px, 4)} px${over}`];
}

/** The run's facts: status, camera (named `cameraName`), arm or projector, kind, options,
 * when, how long, and its error measure. */
function runFacts(run, cameraName) {
  const options = run.options
    ? Object.entries(run.options)
        .map(([k, v]) => `${k}=${v}`)
        .join(", ")
    : "–";
  const error = runError(run);
  return facts({ testid: "run-facts" }, [
    ["Status", statusBadge(run.status, "run-status")],
    ["Camera", runCamera(run, cameraName)],
    run.kind === "hand-eye" && run.arm_id ? ["Arm", `#${run.arm_id}`, { testid: "run-arm" }] : null,
    run.kind === "projector" && run.result
      ? ["Projector", `#${run.result.projector_id}`, { testid: "run-projector" }]
      : null,
    ["Kind", [run.kind, run.source ? ` · ${run.source}` : ""]],
    ["Options", options, { class: "mono small" }],
    ["Created", when(run.created_at)],
    ["Ran for", duration(run.started_at, run.finished_at)],
    error ? [...error, { class: "num", testid: "run-rms" }] : null,
  ]);
}

/** The button that applies a succeeded run; the answer (or the refusal) goes to `notice`, and
 * `state.applied` keeps it applied across redraws. */
function applyButton(run, notice, state) {
  return h(
    "button",
    {
      class: "btn primary",
      type: "button",
      testid: "run-apply",
      disabled: state.applied,
      onClick: async (ev) => {
        const btn = ev.currentTarget;
        btn.disabled = true;
        mount(notice);
        try {
          const answer = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
          state.applied = true;
          btn.textContent = "Applied";
          mount(notice, appliedNotice(run, answer));
        } catch (err) {
          btn.disabled = false;
          mount(notice, errorBox(err, "run-apply-error"));
        }
      },
    },
    state.applied ? "Applied" : applyLabel(run),
  );
}

/** Draw the run: its facts and actions in `header`; its results, its failure or its progress
 * in `body`. */
function drawRun({ header, body, notice }, run, cameraName, state) {
  const actions = h(
    "div",
    { class: "form-actions", style: { marginTop: 0 } },
    run.status === "succeeded" && run.result && applicable(run)
      ? applyButton(run, notice, state)
      : null,
    h("a", { class: "btn", href: "#/calibration" }, "All runs"),
  );
  mount(
    header,
    panel(
      null,
      null,
      h(
        "div",
        { class: "panel-head", style: { marginBottom: 0 } },
        runFacts(run, cameraName),
        actions,
      ),
    ),
  );
  const results = run.status === "succeeded" && run.result ? resultViews(run) : null;
  if (results) mount(body, ...results);
  else if (run.status === "failed" || run.status === "interrupted")
    mount(
      body,
      errorBox(
        { title: `The run ${run.status}`, detail: run.error || "No reason was recorded." },
        "run-error",
      ),
    );
  else mount(body, progressView(run));
}

export async function renderRun(main, [id], _query, setTitle) {
  setTitle(`Calibration run #${id}`);
  const state = { applied: false };
  const boxes = {
    header: h("div"),
    body: h("div", { class: "grid" }),
    notice: h("div", { "aria-live": "assertive" }),
  };
  const { header, body, notice } = boxes;
  mount(main, header, notice, body);

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
      drawRun(boxes, run, cameraName, state);
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
