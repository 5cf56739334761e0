// The Landmarks page's photo detection: a photo and the camera that took it are sent to the
// service, which finds the landmarks in it; each one's outline and what it says are drawn over
// the photo, with a table of where each one is.

import { api } from "../../api.js";
import { choice, field, sending } from "../../forms.js";
import { fmt, h, mount, s, sig, table } from "../../ui.js";

function label(det) {
  if (det.record) return `#${det.record.id} ${det.record.name}`;
  return `${det.kind}: ${det.reason || "not read"}`;
}

/** The photo with each detection's outline and label drawn over it (SVG in image pixels). */
function overlay(url, result) {
  const { width, height } = result;
  const stroke = Math.max(2, width / 300);
  const font = Math.max(12, width / 40);
  return s(
    "svg",
    {
      class: "detect-overlay",
      viewBox: `0 0 ${width} ${height}`,
      role: "img",
      "aria-label": `${result.detections.length} landmark(s) found`,
      testid: "detection-overlay",
    },
    s("image", { href: url, x: 0, y: 0, width, height }),
    result.detections.map((det, i) => {
      const pts = det.outline.map(([u, v]) => `${u},${v}`).join(" ");
      const top = det.outline.reduce((a, b) => (b[1] < a[1] ? b : a), det.outline[0]);
      return s(
        "g",
        { class: `detection ${det.kind}`, testid: `detection-${i}` },
        s("polygon", {
          points: pts,
          class: "outline",
          "stroke-width": stroke,
          testid: "detection-outline",
        }),
        s(
          "text",
          {
            x: top[0],
            y: Math.max(font, top[1] - font / 3),
            "font-size": font,
            // Labels near the right edge end at their corner instead of running off the photo.
            "text-anchor": top[0] > 0.6 * width ? "end" : "start",
            class: "tag",
          },
          label(det),
        ),
      );
    }),
  );
}

function detectionTable(result) {
  if (!result.detections.length) {
    return h("p", { class: "empty", testid: "detections-empty" }, "No landmark found.");
  }
  return h(
    "div",
    { class: "table-wrap" },
    table(
      { testid: "detection-table" },
      ["Kind", "Read", "Distance", "Position (camera)", "σ position"],
      result.detections.map((d) => {
        const sd = [3, 4, 5].map((k) => Math.sqrt(d.cov[k][k]) * 1000);
        return h(
          "tr",
          null,
          h("td", null, d.kind),
          h("td", { testid: "detection-read" }, label(d)),
          h("td", { class: "num" }, `${fmt(d.distance_m, 3)} m`),
          h("td", { class: "num mono" }, d.position.map((v) => fmt(v, 3)).join(", ")),
          h("td", { class: "num" }, `${sd.map((v) => sig(v, 2)).join(" / ")} mm`),
        );
      }),
    ),
  );
}

/** The form that sends a photo (with the camera that took it); what was found is shown in
 * `out`. */
export function detectForm(cameras, out) {
  const usable = cameras.filter((c) => c.K);
  const file = h("input", {
    type: "file",
    accept: "image/*",
    required: true,
    id: "landmark-photo",
    testid: "landmark-photo",
  });
  const camera = choice(
    { id: "detect-camera", testid: "detect-camera", required: true },
    usable.map((c) => [c.id, `${c.name} (${c.width}x${c.height})`]),
  );
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "detect-submit", disabled: !usable.length },
    "Find landmarks",
  );
  let shown = null;
  const detect = async () => {
    if (!file.files.length) return;
    mount(out, h("p", { class: "muted" }, "Detecting…"));
    const result = await api("/landmarks/detect", {
      method: "POST",
      form: { image: file.files[0], camera_id: camera.value },
    });
    if (shown) URL.revokeObjectURL(shown);
    shown = URL.createObjectURL(file.files[0]);
    mount(out, overlay(shown, result), detectionTable(result));
  };
  const form = h(
    "form",
    {
      class: "form-grid wide detect-form",
      testid: "detect-form",
      onSubmit: sending(submit, detect, {
        errors: out,
        testid: "detect-error",
        keep: true,
        toast: true,
      }),
    },
    field("landmark-photo", "Photo", file),
    field("detect-camera", "Camera", camera),
    h("div", { class: "form-actions", style: { marginTop: 0 } }, submit),
  );
  return [
    usable.length
      ? null
      : h(
          "p",
          { class: "empty", testid: "detect-no-camera" },
          "No camera has intrinsics yet: calibrate one to locate landmarks in its photos.",
        ),
    form,
  ];
}
