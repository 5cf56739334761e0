// The Navigation page's projectors: the one paths are planned with (those with a mount pose),
// and the projector calibration on the twin: a run of kind "projector" (POST
// /calibration-runs), followed until it ends; a succeeded run can be applied here (POST
// .../apply), which gives the projector its new mount for the paths planned next and in the 3D
// scene.

import { api, list, poll } from "../../api.js";
import { busy } from "../../forms.js";
import { fmt, h, mount, resultsTable, statusBadge, toast, toastError } from "../../ui.js";

const POLL_MS = 500; // GET a calibration run while it runs
const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);

const named = (p) => (p.T_world_projector ? p.name : `${p.name} (uncalibrated)`);

/** What a finished projector calibration run found: its fit, and (the twin's own check) its
 * errors against the twin's true mount. */
function calibrationFacts(result) {
  const e = result.twin_errors;
  const position = result.T_world_projector.slice(0, 3).map((r) => fmt(r[3], 3));
  return resultsTable("calib-result", [
    ["Spots", String(result.spots), "calib-spots"],
    ["RMS floor error", `${fmt(result.rms_m * 1000, 1)} mm`, "calib-rms"],
    ["Tilt offset", `${fmt((result.tilt_offset_rad * 180) / Math.PI, 3)}°`],
    ["Mount position", `${position.join(", ")} m`, "calib-position"],
    [
      "Uncertainty (one std)",
      `${fmt(result.position_std_m * 1000, 1)} mm, ${fmt(result.rotation_std_deg, 3)}°`,
    ],
    e
      ? [
          "Against the twin",
          `${fmt(e.position_m * 1000, 1)} mm, ${fmt(e.rotation_deg, 3)}°`,
          "calib-twin-errors",
        ]
      : null,
  ]);
}

/** A run's status line: its link, its status and, while it runs, its stage and progress. */
function runLine(run) {
  const p = run.progress;
  const pct = p ? Math.round(100 * p.fraction) : 0;
  return h(
    "p",
    null,
    "Run ",
    h(
      "a",
      { href: `#/calibration/runs/${run.id}`, class: "mono", testid: "calib-run" },
      `#${run.id}`,
    ),
    ": ",
    statusBadge(run.status, "calib-status"),
    run.status === "running" && p
      ? h("span", { class: "small muted", testid: "calib-progress" }, ` ${p.stage}: ${pct} %`)
      : null,
  );
}

/** The button that applies a succeeded run (`apply(run)`) to its projector, named by
 * `nameOf(id)`. */
function applyButton(run, { nameOf, apply }) {
  return h(
    "button",
    {
      class: "btn primary",
      type: "button",
      testid: "calib-apply",
      onClick: async (ev) => {
        const btn = ev.currentTarget;
        try {
          await busy(btn, () => apply(run));
          btn.textContent = "Applied";
          btn.disabled = true;
        } catch (err) {
          toastError(err);
        }
      },
    },
    `Apply to ${nameOf(run.result.projector_id)}`,
  );
}

/** Show a calibration run in `box`: its status, its error, and once it succeeded its fit and
 * the button that applies it. */
function showCalibrationRun(box, run, actions) {
  const done = run.status === "succeeded" && run.result;
  mount(
    box,
    runLine(run),
    run.error ? h("p", { class: "small badge bad", testid: "calib-error" }, run.error) : null,
    done ? calibrationFacts(run.result) : null,
    done ? h("div", { class: "form-actions" }, applyButton(run, actions)) : null,
  );
}

/** Offer `items`, the projectors of `space`, in both selects, keeping the choices that still
 * hold: those with a mount pose plan paths; any of them can be calibrated. */
function fillSelects({ planSelect, calSelect, start, why }, items, space) {
  const planning = planSelect.value;
  const calibrating = calSelect.value;
  planSelect.replaceChildren(
    h("option", { value: "" }, "No projector"),
    ...items.map((p) => h("option", { value: p.id, disabled: !p.T_world_projector }, named(p))),
  );
  calSelect.replaceChildren(...items.map((p) => h("option", { value: p.id }, named(p))));
  if (items.some((p) => String(p.id) === planning && p.T_world_projector))
    planSelect.value = planning;
  if (items.some((p) => String(p.id) === calibrating)) calSelect.value = calibrating;
  start.disabled = !items.length;
  why.hidden = items.length > 0;
  why.textContent = items.length
    ? ""
    : `No projector is registered in ${space.name}: register it (POST /api/v1/projectors ` +
      "with this space's id) to calibrate it here. The digital twin registers its own " +
      "projector in its home when the service runs with INTSPACE_SIMULATION=true.";
}

/** Start a projector's calibration with `start` (the projector of `calSelect`, with rendered
 * `images` or not) and show the run with `showRun` until it ends; `start` stays disabled
 * meanwhile. Returns {stop}. */
function calibrationRuns({ start, calSelect, images, box }, showRun) {
  let reads = null;
  // GET /calibration-runs/{id} until the run ends.
  const follow = (id) => {
    reads?.stop();
    reads = poll(() => api(`/calibration-runs/${id}`), {
      interval: POLL_MS,
      delay: true,
      stopOn4xx: true, // a refusal will not change; keep trying while the service is unreachable
      onValue: (run) => {
        showRun(run);
        if (!TERMINAL.has(run.status)) return true;
        start.disabled = false;
        return false;
      },
      onError: (err) => {
        toastError(err);
        if (err.status >= 400 && err.status < 500) start.disabled = false;
      },
    });
  };

  start.addEventListener("click", async () => {
    if (!calSelect.value) return;
    start.disabled = true;
    reads?.stop();
    try {
      const run = await api("/calibration-runs", {
        method: "POST",
        json: { kind: "projector", projector_id: Number(calSelect.value), images: images.checked },
      });
      showRun(run);
      follow(run.id);
    } catch (err) {
      start.disabled = false;
      mount(
        box,
        h("p", { class: "small badge bad", testid: "calib-error" }, err.detail || err.message),
      );
    }
  });
  return { stop: () => reads?.stop() };
}

/**
 * The projectors of `space` (the one picked in the header): `planSelect` picks the one paths
 * are planned with; `calibration` ({toolbar, why, box}) calibrates any of them. fill(items)
 * gives them the space's projectors. Returns {planSelect, calibration, fill, stop}.
 */
export function projectorViews(space) {
  let projectors = [];
  const planSelect = h("select", { testid: "nav-projector", "aria-label": "Projector" });
  const calSelect = h("select", {
    testid: "calib-projector",
    "aria-label": "Projector to calibrate",
  });
  const images = h("input", { type: "checkbox", testid: "calib-images", checked: true });
  const start = h(
    "button",
    { class: "btn", type: "button", testid: "calib-start", disabled: true },
    "Calibrate projector",
  );
  const box = h("div", { testid: "calib-box", "aria-live": "polite" });
  // Why the calibration cannot start, when it cannot.
  const why = h("p", { class: "small muted", testid: "calib-why", hidden: true });

  const fill = (items) => {
    projectors = items;
    fillSelects({ planSelect, calSelect, start, why }, items, space);
  };

  const apply = async (run) => {
    const applied = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
    toast(`Calibration applied to projector ${applied.name}`);
    fill((await list(`/projectors?space_id=${space.id}`, { limit: 200 })).items);
    if (!planSelect.value) planSelect.value = String(applied.id);
    box.dataset.applied = String(run.id);
  };
  const nameOf = (id) => projectors.find((p) => p.id === id)?.name ?? `projector #${id}`;
  const showRun = (run) => showCalibrationRun(box, run, { nameOf, apply });

  const runs = calibrationRuns({ start, calSelect, images, box }, showRun);

  return {
    planSelect,
    calibration: {
      toolbar: h(
        "div",
        { class: "nav-toolbar" },
        h("label", null, "Projector ", calSelect),
        h("label", null, images, " Detect the spots in rendered images (about 10 s)"),
        start,
      ),
      why,
      box,
    },
    /** Give the views the space's projectors and choose the first calibrated one. */
    fill(items) {
      fill(items);
      const usable = projectors.find((p) => p.T_world_projector);
      if (usable) planSelect.value = String(usable.id);
      if (projectors.length) calSelect.value = String((usable || projectors[0]).id);
    },
    stop: () => runs.stop(),
  };
}
