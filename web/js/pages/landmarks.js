// Landmarks: the registry's landmarks with their printable artwork, detection on an uploaded
// photo (landmarks/detect.js) and the semantic and navigation maps read so far
// (landmarks/maps.js).

import { apiUrl, currentSpace, inSpace, list } from "../api.js";
import { fmt, h, mount, panel, table } from "../ui.js";
import { detectForm } from "./landmarks/detect.js";
import { mapsPanel } from "./landmarks/maps.js";

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
          href: apiUrl(`/landmarks/${landmark.id}/print.${ext}`),
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
