// The panel that starts a run of kind "network": the twin drives the robot's marker past every
// camera.

import { api } from "../../api.js";
import { actionButton, errorSlot, field } from "../../forms.js";
import { h, panel, toast } from "../../ui.js";

export function networkPanel() {
  const error = errorSlot();
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
  const start = async () => {
    const options = {
      seed: Number(seed.value) || 0,
      minutes: minutes.value === "" ? 5 : Number(minutes.value),
    };
    const run = await api("/calibration-runs", {
      method: "POST",
      json: { kind: "network", options },
    });
    toast(`Network calibration run #${run.id} started`);
    location.hash = `#/calibration/runs/${run.id}`;
  };
  const button = actionButton(
    { class: "btn primary", testid: "network-calibrate" },
    "Calibrate the camera network",
    start,
    { errors: error, testid: "network-error" },
  );
  return panel(
    "Network calibration",
    "Every ceiling camera at once: each camera's intrinsics from a chessboard shown to it, " +
      "then the digital twin drives the robot's marker over the floor (its mast raised) and " +
      "every camera's pose comes from a joint refinement with the odometry",
    h(
      "div",
      { class: "form-grid" },
      field("network-seed", "Seed (noise and drive)", seed),
      field("network-minutes", "Drive (minutes, at most 30)", minutes),
      h("div", null, button),
    ),
    error,
  );
}
