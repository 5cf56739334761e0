// Manipulation: the robots' arms, hand-eye calibration of an arm's eye-in-hand camera (a run
// on the twin, its result against the twin's truth, applied to the arm), and fetch tasks on
// the twin with their phases and episode metrics as they run.

import { api, busy, inSpace, list, poll } from "../api.js";
import {
  errorBox,
  fmt,
  h,
  matrixTable,
  mount,
  panel,
  sig,
  statusBadge,
  toast,
  toastError,
} from "../ui.js";

const POLL_MS = 700;
const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);
const PHASES = ["approach", "switch", "look then move", "grasp", "lift and carry"];

function handEyeState(arm) {
  if (!arm.T_ee_camera) return h("span", { class: "badge uncalibrated" }, "none");
  if (arm.hand_eye_run_id)
    return h("span", { class: "badge calibrated" }, `run #${arm.hand_eye_run_id}`);
  return h("span", { class: "badge warn" }, "typed in");
}

function armTable(arms, robots) {
  if (!arms.length) {
    return h(
      "p",
      { class: "empty", testid: "arm-table-empty" },
      "No arm yet: add one to a robot below (or POST /api/v1/arms).",
    );
  }
  const robotName = new Map(robots.map((r) => [r.id, r.name]));
  return h(
    "div",
    { class: "table-wrap" },
    h(
      "table",
      { testid: "arm-table" },
      h(
        "thead",
        null,
        h(
          "tr",
          null,
          ["Id", "Robot", "Name", "Reach", "Closed-form IK", "Hand-eye"].map((t) =>
            h("th", null, t),
          ),
        ),
      ),
      h(
        "tbody",
        null,
        arms.map((a) =>
          h(
            "tr",
            { testid: `arm-row-${a.id}` },
            h("td", { class: "num" }, String(a.id)),
            h("td", null, robotName.get(a.robot_id) || `#${a.robot_id}`),
            h("td", null, a.name),
            // Shoulder to wrist centre fully stretched: |a2| + sqrt(a3^2 + d4^2).
            h(
              "td",
              { class: "num" },
              `${fmt(Math.abs(a.dh.a[1]) + Math.hypot(a.dh.a[2], a.dh.d[3]), 2)} m`,
            ),
            h("td", null, a.closed_form ? "yes" : "no"),
            h("td", { testid: `arm-hand-eye-${a.id}` }, handEyeState(a)),
          ),
        ),
      ),
    ),
  );
}

function addArmForm(robots, onAdded) {
  const error = h("div", { "aria-live": "assertive" });
  const robot = h(
    "select",
    { id: "arm-robot", testid: "arm-robot", required: true },
    robots.map((r) => h("option", { value: String(r.id) }, r.name)),
  );
  const name = h("input", { id: "arm-name", testid: "arm-name", required: true, value: "arm" });
  const submit = h(
    "button",
    { class: "btn", type: "submit", testid: "arm-add", disabled: !robots.length },
    "Add the twin's arm",
  );
  return h(
    "form",
    {
      class: "form-grid",
      testid: "arm-form",
      onSubmit: async (event) => {
        event.preventDefault();
        mount(error);
        try {
          await busy(submit, async () => {
            const arm = await api("/arms", {
              method: "POST",
              json: { robot_id: Number(robot.value), name: name.value },
            });
            toast(`Arm #${arm.id} added`);
            await onAdded();
          });
        } catch (err) {
          mount(error, errorBox(err, "arm-error"));
        }
      },
    },
    robots.length
      ? null
      : h("p", { class: "empty" }, "Register a robot first (POST /api/v1/robots)."),
    h("div", { class: "form-row" }, h("label", { for: "arm-robot" }, "Robot"), robot),
    h("div", { class: "form-row" }, h("label", { for: "arm-name" }, "Name"), name),
    h("div", { class: "form-actions" }, submit),
    error,
  );
}

function armSelect(id, arms) {
  return h(
    "select",
    { id, testid: id, required: true },
    arms.map((a) => h("option", { value: String(a.id) }, `#${a.id} ${a.name}`)),
  );
}

/** Poll `path` until its status is terminal, drawing each state; returns a stop function. */
function follow(path, draw, onDone) {
  const reads = poll(() => api(path), {
    interval: POLL_MS,
    stopOn4xx: true, // a refusal will not change; keep trying while the service is unreachable
    onError: toastError,
    onValue: (item) => {
      draw(item);
      if (!TERMINAL.has(item.status)) return true;
      onDone?.(item);
      return false;
    },
  });
  return () => reads.stop();
}

function progressLine(label, fraction, testid) {
  const pct = Math.round(100 * (fraction || 0));
  return h(
    "label",
    { testid },
    `${label}: ${pct} %`,
    h("progress", { max: 100, value: pct, class: "manip-progress" }),
  );
}

function handEyeResult(run, onApplied) {
  const r = run.result;
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
  const apply = h(
    "button",
    {
      class: "btn primary",
      type: "button",
      testid: "hand-eye-apply",
      onClick: async () => {
        try {
          await busy(apply, async () => {
            const arm = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
            toast(`Hand-eye transform applied to arm #${arm.id}`);
            await onApplied();
          });
        } catch (err) {
          toastError(err);
        }
      },
    },
    "Apply to the arm",
  );
  return h(
    "div",
    { testid: "hand-eye-result" },
    h(
      "dl",
      { class: "facts" },
      rows.map(([k, v]) => [h("dt", null, k), h("dd", null, v)]),
    ),
    h("h3", null, "X = T_ee_camera"),
    matrixTable(r.X, 4, "hand-eye-X"),
    r.methods?.length
      ? h(
          "div",
          { class: "table-wrap" },
          h(
            "table",
            { testid: "hand-eye-methods" },
            h(
              "thead",
              null,
              h(
                "tr",
                null,
                ["Linear method, same views", "Rotation error", "Translation error"].map((t) =>
                  h("th", null, t),
                ),
              ),
            ),
            h(
              "tbody",
              null,
              r.methods.map((m) =>
                h(
                  "tr",
                  null,
                  h("td", null, m.method),
                  h("td", { class: "num" }, `${sig(m.rotation_error_deg, 3)}°`),
                  h("td", { class: "num" }, `${sig(m.translation_error_mm, 3)} mm`),
                ),
              ),
            ),
          ),
        )
      : null,
    h("div", { class: "form-actions" }, apply),
  );
}

function handEyePanel(arms, stops, onApplied) {
  const out = h("div", { class: "manip-out", "aria-live": "polite" });
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
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "hand-eye-start", disabled: !arms.length },
    "Calibrate on the twin",
  );
  const draw = (run) => {
    const head = h(
      "p",
      null,
      `Run #${run.id}`,
      " ",
      statusBadge(run.status, "hand-eye-status"),
    );
    if (run.status === "succeeded") mount(out, head, handEyeResult(run, onApplied));
    else if (TERMINAL.has(run.status))
      mount(
        out,
        head,
        errorBox({ title: `The run ${run.status}`, detail: run.error || "" }, "hand-eye-error"),
      );
    else
      mount(
        out,
        head,
        run.progress ? progressLine(run.progress.stage, run.progress.fraction) : null,
      );
  };
  const form = h(
    "form",
    {
      class: "form-grid",
      testid: "hand-eye-form",
      onSubmit: async (event) => {
        event.preventDefault();
        try {
          await busy(submit, async () => {
            const run = await api("/calibration-runs", {
              method: "POST",
              json: {
                kind: "hand-eye",
                arm_id: Number(arm.value),
                method: method.value,
                twin: {
                  views: Number(views.value),
                  rendered: rendered.checked,
                  seed: seed.value === "" ? null : Number(seed.value),
                },
              },
            });
            stops.handEye?.();
            stops.handEye = follow(`/calibration-runs/${run.id}`, draw);
          });
        } catch (err) {
          mount(out, errorBox(err, "hand-eye-error"));
        }
      },
    },
    h("div", { class: "form-row" }, h("label", { for: "hand-eye-arm" }, "Arm"), arm),
    h("div", { class: "form-row" }, h("label", { for: "hand-eye-method" }, "Method"), method),
    h("div", { class: "form-row" }, h("label", { for: "hand-eye-views" }, "Views"), views),
    h(
      "div",
      { class: "form-row" },
      h("label", { for: "hand-eye-rendered" }, "Rendered images (about 1 s a view)"),
      rendered,
    ),
    h("div", { class: "form-row" }, h("label", { for: "hand-eye-seed" }, "Seed (views)"), seed),
    h("div", { class: "form-actions" }, submit),
  );
  return panel(
    "Hand-eye calibration",
    "The twin's arm shows its eye-in-hand camera a chessboard on the dining table from many " +
      "poses; X = T_ee_camera is solved linearly, then refined by reprojection error. Your " +
      "own arm's pose pairs: POST /api/v1/calibration-runs with source \"poses\"",
    form,
    out,
  );
}

function phaseChips(episode) {
  const byName = new Map(episode.phases.map((p) => [p.name, p.ok]));
  return h(
    "span",
    { class: "phase-chips" },
    PHASES.map((name) => {
      const ok = byName.get(name);
      const state = ok === undefined ? "todo" : ok ? "done" : "failed";
      return h("span", { class: `phase ${state}`, title: `${name}: ${state}` }, name);
    }),
  );
}

function taskView(task) {
  const r = task.result;
  const head = h(
    "p",
    null,
    `Task #${task.id} `,
    statusBadge(task.status, "task-status"),
    " ",
    h("span", { class: "muted", testid: "task-phase" }, task.phase || ""),
  );
  const parts = [head];
  if (!TERMINAL.has(task.status)) parts.push(progressLine("Done", task.progress, "task-progress"));
  if (task.error) parts.push(errorBox({ title: `The task ${task.status}`, detail: task.error }));
  if (r) {
    const facts = [
      ["Episodes", `${r.episodes} of ${r.planned}`],
      ["Success rate", r.success_rate === null ? "–" : `${fmt(100 * r.success_rate, 0)} %`],
      [
        "Final error (median of successes)",
        r.position_error_m === null
          ? "–"
          : `${fmt(r.position_error_m * 1000, 2)} mm, ${fmt(r.rotation_error_deg, 2)}°`,
      ],
      ["Time per episode (median, simulated)", `${fmt(r.time_s, 1)} s`],
      [
        "Hand-eye transform",
        `${r.hand_eye.source === "arm" ? "the arm's" : "calibrated for the task"}: ` +
          `${sig(r.hand_eye.rotation_error_deg, 2)}°, ` +
          `${sig(r.hand_eye.translation_error_mm, 2)} mm from the twin's`,
      ],
    ];
    parts.push(
      h(
        "dl",
        { class: "facts", testid: "task-metrics" },
        facts.map(([k, v]) => [h("dt", null, k), h("dd", null, v)]),
      ),
      h(
        "div",
        { class: "table-wrap" },
        h(
          "table",
          { testid: "episode-table" },
          h(
            "thead",
            null,
            h(
              "tr",
              null,
              ["#", "Phases", "Position error", "Rotation error", "Looks", "Gripper", "Outcome"].map(
                (t) => h("th", null, t),
              ),
            ),
          ),
          h(
            "tbody",
            null,
            r.per_episode.map((e, i) =>
              h(
                "tr",
                { testid: `episode-${i + 1}` },
                h("td", { class: "num" }, String(i + 1)),
                h("td", null, phaseChips(e)),
                h("td", { class: "num" }, `${fmt(e.position_error_mm, 2)} mm`),
                h("td", { class: "num" }, `${fmt(e.rotation_error_deg, 2)}°`),
                h("td", { class: "num" }, String(e.looks)),
                h(
                  "td",
                  { class: "num", title: "Where the fingers stopped when the gripper closed" },
                  e.gripper_opening_mm == null ? "–" : `${fmt(e.gripper_opening_mm, 1)} mm`,
                ),
                h("td", null, e.success ? "fetched" : e.reason),
              ),
            ),
          ),
        ),
      ),
    );
  }
  return parts;
}

function tasksPanel(arms, tasks, stops) {
  const out = h("div", { class: "manip-out", testid: "task-view", "aria-live": "polite" });
  const arm = armSelect("task-arm", arms);
  const episodes = h("input", {
    id: "task-episodes",
    testid: "task-episodes",
    type: "number",
    min: 1,
    max: 100,
    value: "5",
  });
  const show = (id) => {
    stops.task?.();
    stops.task = follow(`/tasks/${id}`, (task) => mount(out, taskView(task)));
  };
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "task-start", disabled: !arms.length },
    "Fetch the box",
  );
  const form = h(
    "form",
    {
      class: "form-grid",
      testid: "task-form",
      onSubmit: async (event) => {
        event.preventDefault();
        try {
          await busy(submit, async () => {
            const task = await api("/tasks", {
              method: "POST",
              json: { kind: "fetch", arm_id: Number(arm.value), episodes: Number(episodes.value) },
            });
            show(task.id);
          });
        } catch (err) {
          mount(out, errorBox(err, "task-error"));
        }
      },
    },
    h("div", { class: "form-row" }, h("label", { for: "task-arm" }, "Arm"), arm),
    h("div", { class: "form-row" }, h("label", { for: "task-episodes" }, "Episodes"), episodes),
    h("div", { class: "form-actions" }, submit),
  );
  const recent = tasks.length
    ? h(
        "ul",
        { class: "task-list", testid: "task-list" },
        tasks.slice(0, 10).map((t) =>
          h(
            "li",
            null,
            h(
              "button",
              { class: "btn small", type: "button", onClick: () => show(t.id) },
              `#${t.id}`,
            ),
            " ",
            statusBadge(t.status),
            t.result?.success_rate != null
              ? ` ${fmt(100 * t.result.success_rate, 0)} % of ${t.result.episodes}`
              : "",
          ),
        ),
      )
    : null;
  return panel(
    "Fetch tasks",
    "On the twin: a marked box lands at random on the dining table; the robot approaches " +
      "with the mark kept in view, switches to look-then-move from its taught view, grasps, " +
      "lifts and carries it",
    form,
    recent,
    out,
  );
}

export async function renderManipulation(main) {
  const stops = {};
  const draw = async () => {
    const [allArms, robots, tasks] = await Promise.all([
      list("/arms", { limit: 200 }),
      list(inSpace("/robots", { unassigned: true }), { limit: 200 }),
      list("/tasks", { limit: 10 }),
    ]);
    // The arms of the space's robots (and of robots in no space).
    const robotIds = new Set(robots.items.map((r) => r.id));
    const arms = { ...allArms, items: allArms.items.filter((a) => robotIds.has(a.robot_id)) };
    const armsBox = h("div", { testid: "arms" }, armTable(arms.items, robots.items));
    const refreshArms = async () => {
      const fresh = (await list("/arms", { limit: 200 })).items.filter((a) =>
        robotIds.has(a.robot_id),
      );
      if (fresh.length !== arms.items.length) return draw();
      mount(armsBox, armTable(fresh, robots.items));
    };
    for (const stop of Object.values(stops)) stop?.();
    mount(
      main,
      panel(
        "Arms",
        "The robots' arms: Denavit-Hartenberg model, joint limits, eye-in-hand camera and its " +
          "hand-eye transform",
        armsBox,
        addArmForm(robots.items, draw),
      ),
      handEyePanel(arms.items, stops, refreshArms),
      tasksPanel(arms.items, tasks.items, stops),
    );
  };
  await draw();
  return () => {
    for (const stop of Object.values(stops)) stop?.();
  };
}
