// The form that starts an intrinsics run: a camera, its input (a correspondences file or
// chessboard photos) and the model to fit (distortion, skew).

import { api } from "../../api.js";
import { choice, errorSlot, field, sending } from "../../forms.js";
import { errorBox, h, mount, toast } from "../../ui.js";

const DISTORTION_MODELS = [
  ["none", "None"],
  ["k1", "k1"],
  ["k1k2", "k1, k2"],
  ["k1k2p1p2", "k1, k2, p1, p2"],
  ["k1k2p1p2k3", "k1, k2, p1, p2, k3"],
];

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

/** The two inputs as a segmented choice; value() is "json" or "photos". */
function sourcePicker() {
  const source = (value, label, checked) =>
    h(
      "label",
      null,
      h("input", { type: "radio", name: "source", value, checked, testid: `run-source-${value}` }),
      label,
    );
  const box = h(
    "div",
    { class: "segmented", role: "radiogroup", "aria-label": "Input" },
    source("json", "Correspondences file (JSON)", true),
    source("photos", "Chessboard photos", false),
  );
  return { box, value: () => box.querySelector("input:checked").value };
}

/** The correspondences file, read and checked when picked (against `cameraOf()`'s size when it
 * gives none); parsed() is the checked document or null. Problems go to `error`. */
function correspondencesPane(cameraOf, error) {
  const file = h("input", {
    id: "run-json-file",
    type: "file",
    accept: "application/json,.json",
    testid: "run-json-file",
  });
  const summary = h(
    "p",
    { class: "small muted", testid: "json-summary" },
    "Pick a JSON file with object_points, image_points and image_size.",
  );
  let parsed = null;
  file.addEventListener("change", async () => {
    parsed = null;
    mount(error);
    const picked = file.files[0];
    if (!picked) return;
    try {
      const cam = cameraOf();
      parsed = parseCorrespondences(await picked.text(), cam ? [cam.width, cam.height] : undefined);
      const n = parsed.image_points.reduce((a, v) => a + v.length, 0);
      const size = parsed.image_size ? parsed.image_size.join(" × ") : "size from the camera";
      summary.textContent = `${picked.name}: ${parsed.image_points.length} views, ${n} points, image ${size}`;
    } catch (err) {
      summary.textContent = picked.name;
      mount(
        error,
        errorBox({ title: "Cannot use this file", detail: err.message }, "run-form-error"),
      );
    }
  });
  const pane = h(
    "div",
    { class: "form-grid wide", testid: "pane-json" },
    field("run-json-file", "Correspondences file", file),
    summary,
  );
  return { pane, parsed: () => parsed };
}

/** The chessboard photos with the board's inner corners and square size. */
function photosPane() {
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
  const pane = h(
    "div",
    { class: "form-grid wide", testid: "pane-photos", hidden: true },
    field("run-files", "Chessboard photos", photos),
    field("run-chessboard", "Inner corners (cols × rows)", board),
    field("run-square", "Square size (m)", square),
  );
  return { pane, photos, board, square };
}

/** The model fitted: the distortion terms and whether skew is estimated; options() as sent. */
function modelFields() {
  const distortion = choice(
    { id: "run-distortion", testid: "run-distortion" },
    DISTORTION_MODELS,
    "k1k2p1p2",
  );
  const skew = h("input", { id: "run-skew", type: "checkbox", testid: "run-skew" });
  const box = h(
    "fieldset",
    { style: { marginTop: "14px" } },
    h("legend", null, "Model"),
    h(
      "div",
      { class: "form-grid" },
      field("run-distortion", "Distortion", distortion),
      h("label", { class: "inline", for: "run-skew" }, skew, "Estimate skew"),
    ),
  );
  return { box, options: () => ({ skew: skew.checked, distortion: distortion.value }) };
}

/** Send the run: the correspondences as JSON, or the photos as a multipart upload. */
function sendRun(camera, json, photos, options) {
  if (json) {
    return api("/calibration-runs", {
      method: "POST",
      json: {
        kind: "intrinsics",
        camera_id: camera.id,
        image_size: json.image_size || [camera.width, camera.height],
        object_points: json.object_points,
        image_points: json.image_points,
        options,
      },
    });
  }
  if (!photos.photos.files.length) throw new Error("Pick the chessboard photos first.");
  return api("/calibration-runs/upload", {
    method: "POST",
    form: {
      camera_id: String(camera.id),
      chessboard: photos.board.value.replace(/\s+/g, "").replace("×", "x"),
      square: photos.square.value,
      distortion: options.distortion,
      skew: String(options.skew),
      files: photos.photos.files,
    },
  });
}

export function startForm(cameras, preselect) {
  const error = errorSlot();
  const camera = choice(
    { id: "run-camera", name: "camera_id", required: true, testid: "run-camera" },
    cameras.map((c) => [c.id, `${c.name} (${c.width}×${c.height})`]),
    preselect,
  );
  const cameraOf = () => cameras.find((c) => String(c.id) === camera.value);
  const sources = sourcePicker();
  const json = correspondencesPane(cameraOf, error);
  const photos = photosPane();
  sources.box.addEventListener("change", () => {
    json.pane.hidden = sources.value() !== "json";
    photos.pane.hidden = !json.pane.hidden;
    mount(error);
  });
  const model = modelFields();
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "run-submit" },
    "Start calibration",
  );
  const start = async () => {
    const isJson = sources.value() === "json";
    if (isJson && !json.parsed()) throw new Error("Pick a correspondences file first.");
    const run = await sendRun(cameraOf(), isJson ? json.parsed() : null, photos, model.options());
    toast(`Calibration run #${run.id} started`);
    location.hash = `#/calibration/runs/${run.id}`;
  };
  const label = h("span", { class: "small group-label" }, "Input");
  return h(
    "form",
    {
      testid: "run-form",
      onSubmit: sending(submit, start, {
        errors: error,
        testid: "run-form-error",
        title: "Cannot start the run",
      }),
    },
    h(
      "div",
      { class: "form-row" },
      field("run-camera", "Camera", camera),
      h("div", null, label, sources.box),
    ),
    h("div", { style: { marginTop: "14px" } }, json.pane, photos.pane),
    model.box,
    h("div", { class: "form-actions" }, submit),
    error,
  );
}
