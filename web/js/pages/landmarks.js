// Landmarks: the registry's landmarks with their printable artwork, detection on an uploaded
// photo (outlines and labels drawn over it), and the semantic and navigation maps read so far.

import { api, currentSpace, inSpace, list } from "../api.js";
import { choice, field, sending } from "../forms.js";
import { drawRooms, planSvg, planTransform } from "../plan.js";
import { fmt, h, mount, panel, s, sig, table } from "../ui.js";

const BASE = "/api/v1";

function printLinks(landmark) {
  if (landmark.kind !== "qr") return h("span", { class: "muted" }, "not a QR landmark");
  return h(
    "span",
    { class: "print-links" },
    ["svg", "pdf", "png"].map((ext) =>
      h(
        "a",
        {
          class: "btn small",
          href: `${BASE}/landmarks/${landmark.id}/print.${ext}`,
          target: "_blank",
          rel: "noopener",
          testid: `print-${ext}-${landmark.id}`,
        },
        ext.toUpperCase(),
      ),
    ),
  );
}

/** What a landmark's payload names, read from its fields (core.landmarks' format: object
 * "ISL1|O|id|class|name|room|...", signpost "ISL1|S|id|name|room|..."): "object #1 blue cup
 * (kitchen)"; "–" for a foreign code. The service checks the checksum when it reads a
 * landmark; this only labels the table. */
function markOf(payload) {
  const f = (payload || "").split("|");
  if (f[0] !== "ISL1" || f.length < 6 || !["O", "S"].includes(f[1])) return "–";
  const [kind, name, room] = f[1] === "O" ? ["object", f[4], f[5]] : ["signpost", f[3], f[4]];
  return `${kind} #${f[2]} ${name}${room ? ` (${room})` : ""}`;
}

function landmarkTable(items) {
  if (!items.length) {
    return h(
      "p",
      { class: "empty", testid: "landmark-table-empty" },
      "No landmarks registered yet (POST /api/v1/landmarks, or `intspace landmark make`).",
    );
  }
  return h(
    "div",
    { class: "table-wrap" },
    table(
      { testid: "landmark-table" },
      ["Id", "Kind", "Mark", "Size", "Payload", "Print"],
      items.map((l) =>
        h(
          "tr",
          { testid: `landmark-row-${l.id}` },
          h("td", { class: "num" }, String(l.id)),
          h("td", null, l.kind),
          h("td", { testid: `landmark-mark-${l.id}` }, markOf(l.payload)),
          h("td", { class: "num" }, `${fmt(l.size_m * 100, 1)} cm`),
          h("td", { class: "mono payload", title: l.payload }, l.payload),
          h("td", null, printLinks(l)),
        ),
      ),
    ),
  );
}

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

function detectForm(cameras, out) {
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

function mapTable(testid, head, rows) {
  if (!rows.length)
    return h("p", { class: "empty", testid: `${testid}-empty` }, "Nothing read yet.");
  const row = (r) =>
    h(
      "tr",
      null,
      r.map((c) => h("td", null, c)),
    );
  return h("div", { class: "table-wrap" }, table({ testid }, head, rows.map(row)));
}

/** The maps on the floor plan, drawn as the Floor and Navigation pages draw theirs: rooms,
 * navigation edges and places (red), objects (blue). */
function mapPlan(rooms, semantic, navigation) {
  const places = navigation.features.filter((f) => f.properties.kind === "place");
  const edges = navigation.features.filter((f) => f.properties.kind === "edge");
  const pts = [
    ...rooms.flatMap((r) => r.polygon || []),
    ...places.map((f) => f.geometry.coordinates),
    ...semantic.features.map((f) => f.geometry.coordinates),
  ];
  if (!pts.length) return null;
  const tf = planTransform(pts, { width: 720, minHeight: 300 });
  const { X, Y } = tf;
  const gRooms = s("g");
  drawRooms(gRooms, rooms, tf);
  const svg = planSvg(
    tf,
    {
      className: "plot floormap maps-plan",
      label: "Semantic and navigation maps on the floor plan",
      testid: "maps-plan",
    },
    gRooms,
    edges.map((f) => {
      const [[ax, ay], [bx, by]] = f.geometry.coordinates;
      return s("line", {
        class: `nav-edge ${f.properties.via}`,
        x1: X(ax),
        y1: Y(ay),
        x2: X(bx),
        y2: Y(by),
        testid: "plan-edge",
      });
    }),
    places.map((f) => {
      const [x, y] = f.geometry.coordinates;
      return s(
        "g",
        { class: "nav-place", testid: "plan-place" },
        s("circle", { cx: X(x), cy: Y(y), r: 6 }),
        s("text", { x: X(x) + 9, y: Y(y) - 6 }, f.properties.name),
      );
    }),
    semantic.features.map((f) => {
      const [x, y] = f.geometry.coordinates;
      return s(
        "g",
        { class: "sem-object", testid: "plan-object" },
        s("rect", { x: X(x) - 5, y: Y(y) - 5, width: 10, height: 10 }),
        s("text", { x: X(x) + 9, y: Y(y) + 14 }, f.properties.name),
      );
    }),
  );
  return h("div", { class: "floor-wrap maps-wrap" }, svg);
}

async function mapsPanel() {
  let semantic;
  let navigation;
  try {
    [semantic, navigation] = await Promise.all([
      api(inSpace("/maps/semantic")),
      api(inSpace("/maps/navigation")),
    ]);
  } catch (err) {
    if (err.status === 409) {
      return panel(
        "Maps",
        "Objects and places read from landmarks",
        h("p", { class: "empty", testid: "maps-missing" }, err.detail),
      );
    }
    throw err;
  }
  const rooms = await list(`/rooms?space_id=${semantic.space_id}`, { limit: 500 });
  const objects = semantic.features.map(({ geometry, properties: p }) => [
    `#${p.id}`,
    p.class,
    p.name,
    p.room,
    geometry.coordinates.map((v) => fmt(v, 2)).join(", "),
    String(p.reads),
    fmt(p.confidence, 3),
  ]);
  const places = navigation.features
    .filter((f) => f.properties.kind === "place")
    .map(({ geometry, properties: p }) => [
      `#${p.id}`,
      p.name,
      p.room,
      geometry.coordinates.map((v) => fmt(v, 2)).join(", "),
      p.neighbours.map((n) => `#${n}`).join(" "),
    ]);
  return panel(
    "Maps",
    "The semantic map (objects, blue) and the navigation map (places and their links, red) " +
      "read from landmarks",
    mapPlan(rooms.items, semantic, navigation),
    h("h3", null, "Objects"),
    mapTable(
      "semantic-table",
      ["Mark", "Class", "Name", "Room", "x, y (m)", "Reads", "Confidence"],
      objects,
    ),
    h("h3", null, "Places"),
    mapTable("places-table", ["Mark", "Name", "Room", "x, y (m)", "Neighbours"], places),
  );
}

export async function renderLandmarks(main) {
  const space = currentSpace();
  const [landmarks, cameras] = await Promise.all([
    list(inSpace("/landmarks", { unassigned: true }), { limit: 500 }),
    list(inSpace("/cameras", { unassigned: true }), { limit: 500 }),
  ]);
  const out = h("div", { class: "detect-result", testid: "detect-result" });
  mount(
    main,
    panel(
      space ? `Landmarks of ${space.name}` : "Landmarks",
      "Printed at true size: the blue frame's side or the red rings' diameter is the size",
      landmarkTable(landmarks.items),
    ),
    panel(
      "Find landmarks in a photo",
      "Pick the camera that took it: its intrinsics locate each landmark",
      detectForm(cameras.items, out),
      out,
    ),
    await mapsPanel(),
  );
}
