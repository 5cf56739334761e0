// Following a run or a task on the twin until it ends, and its progress as a bar.

import { api, poll } from "../../api.js";
import { h, toastError } from "../../ui.js";

const POLL_MS = 700;
export const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);

/** Poll `path` until its status is terminal, drawing each state; returns a stop function. */
export function follow(path, draw, onDone) {
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

export function progressLine(label, fraction, testid) {
  const pct = Math.round(100 * (fraction || 0));
  return h(
    "label",
    { testid },
    `${label}: ${pct} %`,
    h("progress", { max: 100, value: pct, class: "manip-progress" }),
  );
}
