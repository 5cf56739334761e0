// Calibration runs: the form that starts one (chessboard photos or a correspondences file), the
// network calibration, and the runs so far. One run's page is calibration/run.js.

import { api, inSpace, list, settled } from "../api.js";
import {
  duration,
  errorBox,
  fmt,
  h,
  infoBox,
  linkRow,
  mount,
  panel,
  statusBadge,
  table,
  when,
} from "../ui.js";
import { networkPanel } from "./calibration/network.js";
import { startForm } from "./calibration/start.js";

/** A calibration run's cells, by column: its number (a link to its page), its camera (a link,
 * named from `cameras`), its status, RMS and fx (px) and when it was created. The Overview's
 * recent runs show them too. */
export function runCells(r, cameras) {
  const name = cameras.find((c) => c.id === r.camera_id)?.name || `camera ${r.camera_id}`;
  return {
    run: h("td", null, h("a", { href: `#/calibration/runs/${r.id}` }, `#${r.id}`)),
    camera: h("td", null, r.camera_id ? h("a", { href: `#/cameras/${r.camera_id}` }, name) : "–"),
    status: h("td", null, statusBadge(r.status)),
    rms: h("td", { class: "num" }, fmt(r.result?.rms, 4)),
    fx: h("td", { class: "num" }, r.result?.K ? fmt(r.result.K[0][0], 2) : "–"),
    created: h("td", { class: "small muted" }, when(r.created_at)),
  };
}

function runsTable(runs, cameras) {
  const head = ["Run", "Camera", "Kind", "Status", "RMS (px)", "fx", "Created", "Duration"];
  const columns = head.map((t, i) => [t, { class: i === 4 || i === 5 ? "num" : null }]);
  const row = (r) => {
    const cells = runCells(r, cameras);
    return linkRow(
      `#/calibration/runs/${r.id}`,
      { testid: `run-row-${r.id}` },
      cells.run,
      cells.camera,
      h("td", null, [
        r.kind,
        r.source ? h("span", { class: "muted small" }, ` · ${r.source}`) : null,
      ]),
      cells.status,
      cells.rms,
      cells.fx,
      cells.created,
      h("td", { class: "small muted" }, duration(r.started_at, r.finished_at)),
    );
  };
  return table({ testid: "run-table" }, columns, runs.map(row));
}

export async function renderCalibration(main, _params, query) {
  const [{ items: cameras }, runs] = await Promise.all([
    list(inSpace("/cameras", { unassigned: true }), { limit: 200 }),
    settled(list("/calibration-runs", { limit: 50 })),
  ]);
  // A camera linked from its page is offered even when it is of another space than the one
  // picked; the runs shown are the space's cameras' and those of no camera.
  const linked = Number(query.get("camera"));
  if (linked && !cameras.some((c) => c.id === linked)) {
    try {
      cameras.push(await api(`/cameras/${linked}`));
    } catch {
      /* gone: the form offers the space's cameras */
    }
  }
  if (runs.value) {
    const ids = new Set(cameras.map((c) => c.id));
    const kept = runs.value.items.filter((r) => !r.camera_id || ids.has(r.camera_id));
    // Of the newest 50 runs, those of this space: their count is all the page knows.
    if (kept.length < runs.value.items.length) runs.value.total = kept.length;
    runs.value.items = kept;
  }
  const runsBody = runs.error
    ? errorBox(runs.error, "runs-error")
    : runs.value.items.length
      ? h(
          "div",
          { class: "table-wrap" },
          runsTable(runs.value.items, cameras),
          runs.value.total > runs.value.items.length
            ? h(
                "p",
                { class: "small muted" },
                `Showing the newest ${runs.value.items.length} of ${runs.value.total}.`,
              )
            : null,
        )
      : h("p", { class: "empty", testid: "run-table-empty" }, "No calibration runs yet.");
  mount(
    main,
    panel(
      "New calibration run",
      "Intrinsics and distortion by Zhang's method from several views of a planar pattern",
      cameras.length
        ? startForm(cameras, query.get("camera"))
        : infoBox(
            h(
              "span",
              null,
              "Add a camera first on the ",
              h("a", { href: "#/cameras" }, "Cameras"),
              " page.",
            ),
            "run-needs-camera",
          ),
    ),
    networkPanel(),
    panel("Runs", "Newest first", runsBody),
  );
}
