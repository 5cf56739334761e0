// The floor plan as an SVG drawing, the one module every page that draws the plan uses: the
// world -> SVG mapping (world X right, Y up; SVG y down) and what is drawn in it (rooms, walls,
// furniture, cameras, zones, targets with their tracks and covariance ellipses, the twin's
// truth, a robot's pose), the scale bar, and a click on the drawing back in world metres.
// Pages give it groups (<g>) to draw into and keep their own data and refreshes.

import { fmt, s } from "./ui.js";

/**
 * Return the mapping of a plan `width` SVG units across that holds `points` ([x, y] m) with a
 * `margin` (m) around them and `pad` SVG units inside the edge; its height follows the plan's
 * aspect, between `minHeight` and `maxHeight` units. `json` carries the numbers a test needs
 * to aim at a world point.
 */
export function planTransform(
  points,
  { width = 900, minHeight = 320, maxHeight = 760, margin = 0.3, pad = 16 } = {},
) {
  const xs = points.map((p) => p[0]);
  const ys = points.map((p) => p[1]);
  const x0 = Math.min(...xs) - margin;
  const x1 = Math.max(...xs) + margin;
  const y0 = Math.min(...ys) - margin;
  const y1 = Math.max(...ys) + margin;
  const spanX = Math.max(x1 - x0, 1e-6);
  const spanY = Math.max(y1 - y0, 1e-6);
  const height = Math.round(Math.min(Math.max((spanY / spanX) * width, minHeight), maxHeight));
  const scale = Math.min((width - 2 * pad) / spanX, (height - 2 * pad) / spanY);
  const ox = (width - scale * (x1 - x0)) / 2;
  const oy = (height - scale * (y1 - y0)) / 2;
  return {
    W: width,
    H: height,
    scale,
    X: (x) => ox + (x - x0) * scale,
    Y: (y) => height - oy - (y - y0) * scale,
    toWorld: (u, v) => [x0 + (u - ox) / scale, y0 + (height - oy - v) / scale],
    json: { x0, y0, ox, oy, scale, height },
  };
}

/** An <svg> of the plan under `tf`: its view box, its role and label, the mapping for tests. */
export function planSvg(tf, { className, label, testid }, ...children) {
  return s(
    "svg",
    {
      class: className,
      viewBox: `0 0 ${tf.W} ${tf.H}`,
      role: "img",
      "aria-label": label,
      testid,
      "data-transform": JSON.stringify(tf.json),
    },
    ...children,
  );
}

/** The `points` attribute of an SVG poly-line or polygon through world points. */
export const pointsAttr = (pts, { X, Y }) =>
  pts.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" ");

/** Return the area centroid of a simple polygon [[x, y], ...] (the vertex mean when it has no
 * area). */
export function centroid(poly) {
  let a = 0;
  let cx = 0;
  let cy = 0;
  poly.forEach(([x0, y0], i) => {
    const [x1, y1] = poly[(i + 1) % poly.length];
    const cross = x0 * y1 - x1 * y0;
    a += cross;
    cx += (x0 + x1) * cross;
    cy += (y0 + y1) * cross;
  });
  if (Math.abs(a) < 1e-12) return vertexMean(poly);
  return [cx / (3 * a), cy / (3 * a)];
}

function vertexMean(poly) {
  const n = poly.length || 1;
  return [poly.reduce((t, p) => t + p[0], 0) / n, poly.reduce((t, p) => t + p[1], 0) / n];
}

/** Draw each room (at least three corners) into `g`: its polygon and its name at its centroid. */
export function drawRooms(g, rooms, tf) {
  for (const room of rooms) {
    const poly = room.polygon || [];
    if (poly.length < 3) continue;
    g.append(s("polygon", { class: "room", points: pointsAttr(poly, tf) }));
    const [cx, cy] = centroid(poly);
    g.append(
      s(
        "text",
        { class: "room-label", x: tf.X(cx), y: tf.Y(cy), "text-anchor": "middle" },
        room.name,
      ),
    );
  }
}

/** Draw the walls ({start, end, thickness} m) into `g`, each as thick as it is (2 units at
 * least). */
export function drawWalls(g, walls, { X, Y, scale }) {
  for (const w of walls) {
    g.append(
      s("line", {
        class: "plan-wall",
        x1: X(w.start[0]),
        y1: Y(w.start[1]),
        x2: X(w.end[0]),
        y2: Y(w.end[1]),
        "stroke-width": Math.max(2, w.thickness * scale),
      }),
    );
  }
}

/** Draw the furniture's footprints ({name, footprint}) into `g`. */
export function drawFurniture(g, furniture, tf) {
  for (const f of furniture) {
    g.append(
      s(
        "polygon",
        { class: "plan-furniture", points: pointsAttr(f.footprint, tf) },
        s("title", null, f.name),
      ),
    );
  }
}

/**
 * Draw every camera with a pose (T_world_camera) into `g`: a dot, its name, and where its
 * optical axis points on the floor, as a short line (`view: "axis"`) or a wedge of its view
 * (`view: "wedge"`, a circle for a camera looking straight down).
 */
export function drawCameras(g, cameras, tf, { view = "axis" } = {}) {
  for (const c of cameras) {
    const T = c.T_world_camera;
    if (!Array.isArray(T)) continue;
    const [px, py] = [tf.X(T[0][3]), tf.Y(T[1][3])];
    // The optical axis's horizontal component: where the camera looks on the floor.
    const len = Math.hypot(T[0][2], T[1][2]);
    const u = len > 1e-3 ? [T[0][2] / len, -T[1][2] / len] : null;
    if (view === "axis" && u) {
      g.append(
        s("line", { class: "cam-axis", x1: px, y1: py, x2: px + 26 * u[0], y2: py + 26 * u[1] }),
      );
    } else if (view === "wedge" && u) {
      const reach = 40;
      const side = (a) => [
        px + reach * (u[0] * Math.cos(a) - u[1] * Math.sin(a)),
        py + reach * (u[0] * Math.sin(a) + u[1] * Math.cos(a)),
      ];
      g.append(
        s("polygon", { class: "cam-view", points: `${px},${py} ${side(0.45)} ${side(-0.45)}` }),
      );
    } else if (view === "wedge") {
      g.append(s("circle", { class: "cam-view", cx: px, cy: py, r: 16 }));
    }
    const right = px > tf.W * 0.75; // labels near the right edge stay inside the drawing
    g.append(
      s("circle", { class: "cam", cx: px, cy: py, r: 5 }, s("title", null, c.name)),
      s(
        "text",
        {
          class: "cam-label",
          x: right ? px - 8 : px + 8,
          y: py - 7,
          "text-anchor": right ? "end" : "start",
        },
        c.name,
      ),
    );
  }
}

/** Draw a scale bar of a round length (at least `minPx` units long) at the bottom left. */
export function drawScaleBar(g, tf, { minPx = 60 } = {}) {
  const metres = [0.5, 1, 2, 5, 10].find((v) => v * tf.scale >= minPx) || 10;
  g.append(
    s("path", { class: "scale-bar", d: `M12 ${tf.H - 14} v4 h${metres * tf.scale} v-4` }),
    s(
      "text",
      { x: 12 + (metres * tf.scale) / 2, y: tf.H - 18, "text-anchor": "middle" },
      `${metres} m`,
    ),
  );
}

/**
 * Draw the zones (GET /spaces/{id}/zones) into `g`, replacing what it held: each zone's polygon
 * with its name and occupancy; rooms (read-only zones, whose polygons the plan draws already)
 * only their occupancy, under their name.
 */
export function drawZones(g, zones, tf) {
  g.replaceChildren();
  for (const z of zones) {
    const [cx, cy] = vertexMean(z.polygon);
    const occupied = (z.occupancy || 0) > 0;
    const label = `${z.name}: ${z.occupancy ?? "–"}`;
    const shape = z.read_only
      ? null
      : s("polygon", {
          class: `zone${occupied ? " occupied" : ""}`,
          points: pointsAttr(z.polygon, tf),
        });
    const text = s(
      "text",
      {
        class: `zone-label${occupied ? " occupied" : ""}`,
        x: tf.X(cx),
        y: tf.Y(cy) + (z.read_only ? 14 : 0),
        "text-anchor": "middle",
      },
      z.read_only ? `👤 ${z.occupancy ?? "–"}` : label,
    );
    g.append(
      s(
        "g",
        {
          testid: z.read_only ? `zone-room-${z.room_id}` : `zone-${z.id}`,
          "data-occupancy": z.occupancy ?? "",
          "data-slug": z.slug,
        },
        shape,
        text,
        s("title", null, `${label} (${z.read_only ? "room" : "zone"} ${z.slug})`),
      ),
    );
  }
}

/**
 * Return the 2-sigma ellipse of a 2x2 covariance (m^2): semi-axes a >= b (m) and the angle of
 * a from world +X (rad). Eigen-decomposition of a symmetric 2x2 matrix in closed form.
 */
export function ellipse2Sigma(cov) {
  const [[sxx, sxy], [, syy]] = cov;
  const mean = (sxx + syy) / 2;
  const r = Math.hypot((sxx - syy) / 2, sxy);
  const l1 = Math.max(mean + r, 0);
  const l2 = Math.max(mean - r, 0);
  return {
    a: 2 * Math.sqrt(l1),
    b: 2 * Math.sqrt(l2),
    angle: 0.5 * Math.atan2(2 * sxy, sxx - syy),
  };
}

/** The kind a target is drawn as: robot, person, or unknown for anything else. */
export const targetKind = (t) => (["robot", "person"].includes(t.kind) ? t.kind : "unknown");

/** Draw tracks ({label, kind, points: [[x, y], ...], testid, ended}) with two points or more
 * into `g`, replacing what it held. */
export function drawTracks(g, tracks, tf) {
  g.replaceChildren(
    ...tracks
      .filter((tr) => tr.points.length > 1)
      .map((tr) =>
        s("polyline", {
          class: `track${tr.ended ? " ended" : ""} ${tr.kind || "unknown"}`,
          points: pointsAttr(tr.points, tf),
          testid: tr.testid,
          "data-points": tr.ended ? null : tr.points.length,
        }),
      ),
  );
}

/** The 2-sigma ellipse of a located target at `xy`, drawn `enlarge` times its size. */
function covarianceEllipse(t, kind, enlarge, { X, Y, scale }) {
  const [x, y] = t.xy;
  const e = ellipse2Sigma(t.cov);
  return s("ellipse", {
    class: `cov ${kind}`,
    cx: X(x),
    cy: Y(y),
    rx: Math.max(e.a * scale * enlarge, 0.5),
    ry: Math.max(e.b * scale * enlarge, 0.5),
    // SVG angles turn clockwise (y down): the world angle with its sign flipped.
    transform: `rotate(${((-e.angle * 180) / Math.PI).toFixed(3)} ${X(x)} ${Y(y)})`,
    testid: `cov-${t.label}`,
    "data-a": e.a,
    "data-b": e.b,
    "data-scale": enlarge,
  });
}

/** The marker of a located target: a square robot, a round person, a triangle otherwise. */
function targetMarker(t, kind, { X, Y }) {
  const [x, y] = t.xy;
  const shape =
    kind === "robot"
      ? s("rect", { x: -7, y: -7, width: 14, height: 14, rx: 3 })
      : kind === "person"
        ? s("circle", { r: 6 })
        : s("path", { d: "M0 -8 L7 5 L-7 5 Z" });
  return s(
    "g",
    {
      class: `target ${kind}`,
      transform: `translate(${X(x)} ${Y(y)})`,
      testid: `target-${t.label}`,
      "data-x": x,
      "data-y": y,
      "data-kind": kind,
    },
    shape,
    s("text", { x: 10, y: -8 }, t.label),
    s("title", null, `${t.label}: (${fmt(x, 3)}, ${fmt(y, 3)}) m`),
  );
}

/**
 * Draw located targets ({label, kind, xy, cov?}) into `gEllipses` (their 2-sigma ellipses,
 * `enlarge(kind)` times their size) and `gTargets` (their markers), replacing what they held.
 */
export function drawTargets(gEllipses, gTargets, targets, tf, enlarge = () => 1) {
  gEllipses.replaceChildren();
  gTargets.replaceChildren();
  for (const t of targets) {
    const kind = targetKind(t);
    if (t.cov) gEllipses.append(covarianceEllipse(t, kind, enlarge(kind), tf));
    gTargets.append(targetMarker(t, kind, tf));
  }
}

/** Draw the digital twin's ground truth (its robot's pose, its people) into `g`, dashed;
 * `twin` null clears it. */
export function drawTruth(g, twin, { X, Y, scale }) {
  g.replaceChildren();
  if (twin?.robot) {
    const { x, y, theta } = twin.robot;
    const r = Math.max(0.18 * scale, 6);
    g.append(
      s(
        "g",
        {
          class: "truth robot",
          transform: `translate(${X(x)} ${Y(y)}) rotate(${((-theta * 180) / Math.PI).toFixed(2)})`,
          testid: "robot-truth",
          "data-x": x,
          "data-y": y,
        },
        s("circle", { r }),
        s("line", { x1: 0, y1: 0, x2: r, y2: 0 }),
      ),
    );
  }
  for (const p of twin?.people || []) {
    g.append(s("circle", { class: "truth person", cx: X(p.x), cy: Y(p.y), r: 9 }));
  }
}

/** A robot at pose (x, y, theta) as its base (radius `radius` m, 4 units at least) with a
 * tick along its heading; `attrs` go on its group. */
export function robotPose({ x, y, theta }, radius, { X, Y, scale }, attrs = {}, ...children) {
  const r = Math.max(4, radius * scale);
  return s(
    "g",
    { class: "plan-robot", ...attrs },
    s("circle", { cx: X(x), cy: Y(y), r }),
    s("line", {
      x1: X(x),
      y1: Y(y),
      x2: X(x) + r * Math.cos(theta),
      y2: Y(y) - r * Math.sin(theta),
    }),
    ...children,
  );
}

/** The world point (m) under a mouse event on the plan's `svg`, or null when the SVG has no
 * screen mapping (not laid out). */
export function eventToWorld(svg, tf, ev) {
  const m = svg.getScreenCTM();
  if (!m) return null;
  const p = new DOMPoint(ev.clientX, ev.clientY).matrixTransform(m.inverse());
  return tf.toWorld(p.x, p.y);
}
