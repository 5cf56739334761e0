// The Floor page's digital twin panel: its clock and controls (pause, resume, reset), read
// again every second, and its ground truth (robot pose, people) drawn dashed on the plan. In
// another space than the twin's home it only says where the twin runs.

import { api, poll, spaceById } from "../../api.js";
import { actionButton } from "../../forms.js";
import { drawTruth } from "../../plan.js";
import { fmt, h, infoBox, mount } from "../../ui.js";

const TWIN_MS = 1000;

/** The twin's facts: state, sim time, frame rate, the robot's error, the scene. */
function twinFacts(tw, paused) {
  return h(
    "dl",
    { class: "facts" },
    h("dt", null, "State"),
    h(
      "dd",
      null,
      h(
        "span",
        { class: `badge ${paused ? "warn" : "ok"}`, testid: "twin-status" },
        paused ? "paused" : "running",
      ),
    ),
    h("dt", null, "Sim time"),
    h("dd", { class: "num", testid: "twin-time" }, `${fmt(tw.sim_time ?? tw.t, 1)} s`),
    tw.rate_hz ? [h("dt", null, "Frame rate"), h("dd", null, `${fmt(tw.rate_hz, 1)} Hz`)] : null,
    tw.robot_error_rms_m !== undefined && tw.robot_error_rms_m !== null
      ? [
          h("dt", null, "Robot error (RMS)"),
          h(
            "dd",
            { class: "num", testid: "twin-error" },
            `${fmt(tw.robot_error_rms_m * 100, 2)} cm`,
          ),
        ]
      : null,
    tw.scene ? [h("dt", null, "Scene"), h("dd", null, tw.scene)] : null,
  );
}

/** The note shown when the twin is off (or its state cannot be read: `err`). */
function twinOffNote(err) {
  return infoBox(
    err && err.status && err.status !== 404 && err.status !== 503
      ? `The digital twin's state could not be read: ${err.message}`
      : "The digital twin is not running. Start the service with INTSPACE_SIMULATION=true " +
          "to see the simulated home alive; positions sent by other sources still show here.",
    "twin-off",
  );
}

/**
 * The twin's panel content for `space`, from its first state `twin0` ({value} or {error}):
 * its truth is drawn into `gTruth` under `tf`; `onReset()` runs after a reset. Returns {box,
 * stop}.
 */
export function twinPanel(space, twin0, { gTruth, tf, onReset }) {
  const box = h("div", { testid: "twin" });
  const tw0 = twin0.value;
  // The twin's controls and ground truth belong to its home: another space has neither.
  if (space && tw0?.enabled && tw0.space_id && tw0.space_id !== space.id) {
    const home = spaceById(tw0.space_id)?.name || `space ${tw0.space_id}`;
    mount(
      box,
      infoBox(
        `The digital twin runs in ${home}, not in ${space.name}: the positions here come from ` +
          `${space.name}'s own cameras. Pick ${home} in the header for the twin's controls.`,
        "twin-elsewhere",
      ),
    );
    return { box, stop: () => {} };
  }
  let reads = null;
  const control = (action, label) =>
    actionButton({ class: "btn small", testid: `twin-${action}` }, label, async () => {
      await api(`/twin/${action}`, { method: "POST" });
      if (action === "reset") onReset();
      reads?.now();
    });
  const off = (err) => {
    drawTruth(gTruth, null, tf);
    mount(box, twinOffNote(err));
  };
  const show = (tw) => {
    if (!tw || tw.enabled === false) {
      off(null);
      return;
    }
    const paused = tw.paused || tw.running === false;
    const actions = paused ? control("resume", "Resume") : control("pause", "Pause");
    mount(
      box,
      twinFacts(tw, paused),
      h("div", { class: "form-actions" }, actions, control("reset", "Reset")),
    );
    drawTruth(gTruth, tw, tf);
  };
  if (twin0.error) off(twin0.error);
  else show(tw0);
  reads = poll(() => api("/twin"), { interval: TWIN_MS, delay: true, onValue: show, onError: off });
  return { box, stop: () => reads.stop() };
}
