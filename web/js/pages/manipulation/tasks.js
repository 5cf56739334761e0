// Fetch tasks on the twin: start one, follow it with its phases, and its episode metrics.

import { api } from "../../api.js";
import { formRow, sending } from "../../forms.js";
import { errorBox, facts, fmt, h, mount, panel, sig, statusBadge, table } from "../../ui.js";
import { armSelect } from "./arms.js";
import { follow, progressLine, TERMINAL } from "./follow.js";

const PHASES = ["approach", "switch", "look then move", "grasp", "lift and carry"];

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

/** The task's figures: episodes, success rate, final error, time, and the hand-eye transform
 * it used against the twin's. */
function taskFacts(r) {
  return facts({ testid: "task-metrics" }, [
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
  ]);
}

/** One row an episode: its phases, errors, looks, where the gripper closed and the outcome. */
function episodeTable(episodes) {
  const head = ["#", "Phases", "Position error", "Rotation error", "Looks", "Gripper", "Outcome"];
  const row = (e, i) =>
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
    );
  return h(
    "div",
    { class: "table-wrap" },
    table({ testid: "episode-table" }, head, episodes.map(row)),
  );
}

function taskView(task) {
  const head = h(
    "p",
    null,
    `Task #${task.id} `,
    statusBadge(task.status, "task-status"),
    " ",
    h("span", { class: "muted", testid: "task-phase" }, task.phase || ""),
  );
  return [
    head,
    TERMINAL.has(task.status) ? null : progressLine("Done", task.progress, "task-progress"),
    task.error ? errorBox({ title: `The task ${task.status}`, detail: task.error }) : null,
    task.result ? [taskFacts(task.result), episodeTable(task.result.per_episode)] : null,
  ];
}

/** The newest tasks as buttons that show one (`show(id)`), or null when there are none. */
function recentTasks(tasks, show) {
  if (!tasks.length) return null;
  return h(
    "ul",
    { class: "task-list", testid: "task-list" },
    tasks
      .slice(0, 10)
      .map((t) =>
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
  );
}

export function tasksPanel(arms, tasks, stops) {
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
  const start = async () => {
    const json = { kind: "fetch", arm_id: Number(arm.value), episodes: Number(episodes.value) };
    show((await api("/tasks", { method: "POST", json })).id);
  };
  const form = h(
    "form",
    {
      class: "form-grid",
      testid: "task-form",
      onSubmit: sending(submit, start, { errors: out, testid: "task-error", keep: true }),
    },
    formRow("task-arm", "Arm", arm),
    formRow("task-episodes", "Episodes", episodes),
    h("div", { class: "form-actions" }, submit),
  );
  return panel(
    "Fetch tasks",
    "On the twin: a marked box lands at random on the dining table; the robot approaches " +
      "with the mark kept in view, switches to look-then-move from its taught view, grasps, " +
      "lifts and carries it",
    form,
    recentTasks(tasks, show),
    out,
  );
}
