// The robots' arms: their table, the form that adds the twin's arm to a robot, and the select
// of an arm the other panels use.

import { api } from "../../api.js";
import { errorSlot, formRow, sending, choice } from "../../forms.js";
import { fmt, h, table, toast } from "../../ui.js";

function handEyeState(arm) {
  if (!arm.T_ee_camera) return h("span", { class: "badge uncalibrated" }, "none");
  if (arm.hand_eye_run_id)
    return h("span", { class: "badge calibrated" }, `run #${arm.hand_eye_run_id}`);
  return h("span", { class: "badge warn" }, "typed in");
}

export function armTable(arms, robots) {
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
    table(
      { testid: "arm-table" },
      ["Id", "Robot", "Name", "Reach", "Closed-form IK", "Hand-eye"],
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
  );
}

export function addArmForm(robots, onAdded) {
  const error = errorSlot();
  const robot = choice(
    { id: "arm-robot", testid: "arm-robot", required: true },
    robots.map((r) => [r.id, r.name]),
  );
  const name = h("input", { id: "arm-name", testid: "arm-name", required: true, value: "arm" });
  const submit = h(
    "button",
    { class: "btn", type: "submit", testid: "arm-add", disabled: !robots.length },
    "Add the twin's arm",
  );
  const add = async () => {
    const arm = await api("/arms", {
      method: "POST",
      json: { robot_id: Number(robot.value), name: name.value },
    });
    toast(`Arm #${arm.id} added`);
    await onAdded();
  };
  return h(
    "form",
    {
      class: "form-grid",
      testid: "arm-form",
      onSubmit: sending(submit, add, { errors: error, testid: "arm-error" }),
    },
    robots.length
      ? null
      : h("p", { class: "empty" }, "Register a robot first (POST /api/v1/robots)."),
    formRow("arm-robot", "Robot", robot),
    formRow("arm-name", "Name", name),
    h("div", { class: "form-actions" }, submit),
    error,
  );
}

/** A select of `arms` with id (and testid) `id`. */
export function armSelect(id, arms) {
  return choice(
    { id, testid: id, required: true },
    arms.map((a) => [a.id, `#${a.id} ${a.name}`]),
  );
}
