// The Landmarks page's maps: the semantic map (objects) and the navigation map (places and
// their links) read from landmarks, on the floor plan and in tables.

import { api, inSpace, list } from "../../api.js";
import { drawRooms, planSvg, planTransform } from "../../plan.js";
import { fmt, h, panel, s, table } from "../../ui.js";

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

/** The Maps panel: the plan, the objects' and the places' tables (or why there are no maps). */
export async function mapsPanel() {
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
