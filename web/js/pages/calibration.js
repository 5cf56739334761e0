// Calibration runs: start one (chessboard photos or a correspondences file), watch it, apply it.

import { api, busy, inSpace, list } from "../api.js";
import {
  duration,
  errorBox,
  fmt,
  h,
  infoBox,
  mount,
  panel,
  statusBadge,
  toast,
  when,
} from "../ui.js";

const DISTORTION_MODELS = [
  ["none", "None"],
  ["k1", "k1"],
  ["k1k2", "k1, k2"],
  ["k1k2p1p2", "k1, k2, p1, p2"],
  ["k1k2p1p2k3", "k1, k2, p1, p2, k3"],
];
// The acceptance targets of a network calibration in the default simulated home (spec 02):
// focal length within 1 %, position within 2 cm, orientation within 0.3 degrees.

/**
 * Read a correspondences file: {"object_points": views of Nx3 (or one Nx3 shared by all views),
 * "image_points": views of Nx2, "image_size": [w, h] (optional)}. Throws with a readable message.
 */
export function parseCorrespondences(text, fallbackSize) {
  let data;
  try {
    data = JSON.parse(text);
  } catch (err) {
    throw new Error(`The file is not valid JSON (${err.message}).`);
  }
  const img = data.image_points;
  let obj = data.object_points;
  if (!Array.isArray(img) || !img.length || !Array.isArray(img[0]) || !Array.isArray(img[0][0])) {
    throw new Error(
      'The file needs "image_points": a list of views, each a list of [u, v] pixels.',
    );
  }
  if (Array.isArray(obj) && obj.length && typeof obj[0][0] === "number") obj = img.map(() => obj);
  if (!Array.isArray(obj) || obj.length !== img.length) {
    throw new Error(
      'The file needs "object_points": one list of [X, Y, Z] per view (or one shared list).',
    );
  }
  img.forEach((view, i) => {
    if (view.length !== obj[i].length) {
      throw new Error(
        `View ${i + 1} has ${view.length} image points but ${obj[i].length} object points.`,
      );
    }
  });
  const size = data.image_size || fallbackSize;
  return { object_points: obj, image_points: img, image_size: size };
}

function runsTable(runs, cameras) {
  const name = (id) => cameras.find((c) => c.id === id)?.name || (id ? `camera ${id}` : "–");
  return h(
    "table",
    { testid: "run-table" },
    h(
      "thead",
      null,
      h(
        "tr",
        null,
        ["Run", "Camera", "Kind", "Status", "RMS (px)", "fx", "Created", "Duration"].map((t, i) =>
          h("th", { class: i === 4 || i === 5 ? "num" : null }, t),
        ),
      ),
    ),
    h(
      "tbody",
      null,
      runs.map((r) =>
        h(
          "tr",
          {
            class: "link-row",
            testid: `run-row-${r.id}`,
            onClick: (ev) => {
              if (ev.target.tagName !== "A") location.hash = `#/calibration/runs/${r.id}`;
            },
          },
          h("td", null, h("a", { href: `#/calibration/runs/${r.id}` }, `#${r.id}`)),
          h(
            "td",
            null,
            r.camera_id ? h("a", { href: `#/cameras/${r.camera_id}` }, name(r.camera_id)) : "–",
          ),
          h("td", null, [
            r.kind,
            r.source ? h("span", { class: "muted small" }, ` · ${r.source}`) : null,
          ]),
          h("td", null, statusBadge(r.status)),
          h("td", { class: "num" }, fmt(r.result?.rms, 4)),
          h("td", { class: "num" }, r.result?.K ? fmt(r.result.K[0][0], 2) : "–"),
          h("td", { class: "small muted" }, when(r.created_at)),
          h("td", { class: "small muted" }, duration(r.started_at, r.finished_at)),
        ),
      ),
    ),
  );
}

function startForm(cameras, preselect) {
  const error = h("div", { "aria-live": "assertive" });
  const camera = h(
    "select",
    { id: "run-camera", name: "camera_id", required: true, testid: "run-camera" },
    cameras.map((c) =>
      h(
        "option",
        { value: String(c.id), selected: String(c.id) === preselect },
        `${c.name} (${c.width}×${c.height})`,
      ),
    ),
  );
  const source = (value, label, checked) =>
    h(
      "label",
      null,
      h("input", { type: "radio", name: "source", value, checked, testid: `run-source-${value}` }),
      label,
    );
  const sources = h(
    "div",
    { class: "segmented", role: "radiogroup", "aria-label": "Input" },
    source("json", "Correspondences file (JSON)", true),
    source("photos", "Chessboard photos", false),
  );

  const jsonFile = h("input", {
    id: "run-json-file",
    type: "file",
    accept: "application/json,.json",
    testid: "run-json-file",
  });
  const jsonSummary = h(
    "p",
    { class: "small muted", testid: "json-summary" },
    "Pick a JSON file with object_points, image_points and image_size.",
  );
  let parsed = null;
  jsonFile.addEventListener("change", async () => {
    parsed = null;
    mount(error);
    const file = jsonFile.files[0];
    if (!file) return;
    try {
      const cam = cameras.find((c) => String(c.id) === camera.value);
      parsed = parseCorrespondences(await file.text(), cam ? [cam.width, cam.height] : undefined);
      const n = parsed.image_points.reduce((a, v) => a + v.length, 0);
      const size = parsed.image_size ? parsed.image_size.join(" × ") : "size from the camera";
      const views = parsed.image_points.length;
      jsonSummary.textContent = `${file.name}: ${views} views, ${n} points, image ${size}`;
    } catch (err) {
      jsonSummary.textContent = file.name;
      mount(
        error,
        errorBox({ title: "Cannot use this file", detail: err.message }, "run-form-error"),
      );
    }
  });
  const photos = h("input", {
    id: "run-files",
    type: "file",
    multiple: true,
    accept: "image/png,image/jpeg,image/bmp,image/tiff",
    testid: "run-files",
  });
  const board = h("input", {
    id: "run-chessboard",
    value: "9x6",
    pattern: "\\d+\\s*[xX×]\\s*\\d+",
    title: "inner corners, columns x rows, e.g. 9x6",
    testid: "run-chessboard",
  });
  const square = h("input", {
    id: "run-square",
    type: "number",
    step: "any",
    min: "0",
    value: "0.025",
    testid: "run-square",
  });

  const jsonPane = h(
    "div",
    { class: "form-grid wide", testid: "pane-json" },
    h("label", { for: "run-json-file" }, "Correspondences file", jsonFile),
    jsonSummary,
  );
  const photoPane = h(
    "div",
    { class: "form-grid wide", testid: "pane-photos", hidden: true },
    h("label", { for: "run-files" }, "Chessboard photos", photos),
    h("label", { for: "run-chessboard" }, "Inner corners (cols × rows)", board),
    h("label", { for: "run-square" }, "Square size (m)", square),
  );
  sources.addEventListener("change", () => {
    const isJson = sources.querySelector("input:checked").value === "json";
    jsonPane.hidden = !isJson;
    photoPane.hidden = isJson;
    mount(error);
  });

  const distortion = h(
    "select",
    { id: "run-distortion", testid: "run-distortion" },
    DISTORTION_MODELS.map(([v, label]) =>
      h("option", { value: v, selected: v === "k1k2p1p2" }, label),
    ),
  );
  const skew = h("input", { id: "run-skew", type: "checkbox", testid: "run-skew" });
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "run-submit" },
    "Start calibration",
  );

  const form = h(
    "form",
    {
      testid: "run-form",
      onSubmit: async (ev) => {
        ev.preventDefault();
        mount(error);
        const isJson = sources.querySelector("input:checked").value === "json";
        const options = { skew: skew.checked, distortion: distortion.value };
        try {
          submit.disabled = true;
          let run;
          if (isJson) {
            if (!parsed) throw new Error("Pick a correspondences file first.");
            const cam = cameras.find((c) => String(c.id) === camera.value);
            run = await api("/calibration-runs", {
              method: "POST",
              json: {
                kind: "intrinsics",
                camera_id: Number(camera.value),
                image_size: parsed.image_size || [cam.width, cam.height],
                object_points: parsed.object_points,
                image_points: parsed.image_points,
                options,
              },
            });
          } else {
            if (!photos.files.length) throw new Error("Pick the chessboard photos first.");
            run = await api("/calibration-runs/upload", {
              method: "POST",
              form: {
                camera_id: camera.value,
                chessboard: board.value.replace(/\s+/g, "").replace("×", "x"),
                square: square.value,
                distortion: options.distortion,
                skew: String(options.skew),
                files: photos.files,
              },
            });
          }
          toast(`Calibration run #${run.id} started`);
          location.hash = `#/calibration/runs/${run.id}`;
        } catch (err) {
          mount(
            error,
            errorBox(
              err.title ? err : { title: "Cannot start the run", detail: err.message },
              "run-form-error",
            ),
          );
        } finally {
          submit.disabled = false;
        }
      },
    },
    h(
      "div",
      { class: "form-row" },
      h("label", { for: "run-camera" }, "Camera", camera),
      h(
        "div",
        null,
        h(
          "span",
          {
            class: "small",
            style: {
              display: "block",
              marginBottom: "5px",
              fontWeight: 550,
              color: "var(--ink-2)",
            },
          },
          "Input",
        ),
        sources,
      ),
    ),
    h("div", { style: { marginTop: "14px" } }, jsonPane, photoPane),
    h(
      "fieldset",
      { style: { marginTop: "14px" } },
      h("legend", null, "Model"),
      h(
        "div",
        { class: "form-grid" },
        h("label", { for: "run-distortion" }, "Distortion", distortion),
        h("label", { class: "inline", for: "run-skew" }, skew, "Estimate skew"),
      ),
    ),
    h("div", { class: "form-actions" }, submit),
    error,
  );
  return form;
}

/** Start a run of kind "network": the twin drives the robot's marker past every camera. */
function networkPanel() {
  const error = h("div", { "aria-live": "assertive" });
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
  const button = h(
    "button",
    {
      class: "btn primary",
      type: "button",
      testid: "network-calibrate",
      onClick: async () => {
        mount(error);
        try {
          await busy(button, async () => {
            const run = await api("/calibration-runs", {
              method: "POST",
              json: {
                kind: "network",
                options: {
                  seed: Number(seed.value) || 0,
                  minutes: minutes.value === "" ? 5 : Number(minutes.value),
                },
              },
            });
            toast(`Network calibration run #${run.id} started`);
            location.hash = `#/calibration/runs/${run.id}`;
          });
        } catch (err) {
          mount(error, errorBox(err, "network-error"));
        }
      },
    },
    "Calibrate the camera network",
  );
  return panel(
    "Network calibration",
    "Every ceiling camera at once: each camera's intrinsics from a chessboard shown to it, " +
      "then the digital twin drives the robot's marker over the floor (its mast raised) and " +
      "every camera's pose comes from a joint refinement with the odometry",
    h(
      "div",
      { class: "form-grid" },
      h("label", { for: "network-seed" }, "Seed (noise and drive)", seed),
      h("label", { for: "network-minutes" }, "Drive (minutes, at most 30)", minutes),
      h("div", null, button),
    ),
    error,
  );
}

export async function renderCalibration(main, _params, query) {
  const [{ items: cameras }, runs] = await Promise.all([
    list(inSpace("/cameras", { unassigned: true }), { limit: 200 }),
    list("/calibration-runs", { limit: 50 }).then(
      (v) => ({ v }),
      (e) => ({ e }),
    ),
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
  if (runs.v) {
    const ids = new Set(cameras.map((c) => c.id));
    const kept = runs.v.items.filter((r) => !r.camera_id || ids.has(r.camera_id));
    // Of the newest 50 runs, those of this space: their count is all the page knows.
    if (kept.length < runs.v.items.length) runs.v.total = kept.length;
    runs.v.items = kept;
  }
  const runsBody = runs.e
    ? errorBox(runs.e, "runs-error")
    : runs.v.items.length
      ? h(
          "div",
          { class: "table-wrap" },
          runsTable(runs.v.items, cameras),
          runs.v.total > runs.v.items.length
            ? h(
                "p",
                { class: "small muted" },
                `Showing the newest ${runs.v.items.length} of ${runs.v.total}.`,
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
