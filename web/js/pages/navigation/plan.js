// The Navigation page's plan: the floor plan paths are planned on (rooms, walls, furniture);
// a click sets the start, the next the goal, and the path is planned (POST /paths) with the
// projector chosen; a follow run's robot, trail and laser spot are drawn on it.

import { api } from "../../api.js";
import {
  drawFurniture,
  drawRooms,
  drawWalls,
  eventToWorld,
  planSvg,
  planTransform,
  pointsAttr,
  robotPose,
} from "../../plan.js";
import { fmt, h, mount, s } from "../../ui.js";

const W = 900; // SVG user units across; the height follows the plan's aspect, at least 320

/** The plan's drawing of `drawing` (GET /paths/floor-plan): rooms and obstacles drawn, groups
 * for the path, the run and the start and goal marks. */
function planDrawing(drawing) {
  const extent = drawing.rooms.flatMap((r) => r.polygon);
  const tf = planTransform(
    extent.length
      ? extent
      : [
          [0, 0],
          [5, 4],
        ],
    { width: W, minHeight: 320 },
  );
  const svg = planSvg(tf, {
    className: "plot floormap nav-plan",
    label: "Floor plan: click a start, then a goal",
    testid: "nav-map",
  });
  const g = { rooms: s("g"), obstacles: s("g"), path: s("g"), run: s("g"), marks: s("g") };
  svg.append(...Object.values(g));
  drawRooms(g.rooms, drawing.rooms, tf);
  drawWalls(g.obstacles, drawing.walls, tf);
  drawFurniture(g.obstacles, drawing.furniture, tf);
  return { tf, svg, g };
}

/** The planned path's summary: its id, length, bends and how long the projector draws it. */
function pathSummary(path) {
  const traj = path.trajectory;
  return h(
    "p",
    null,
    "Path ",
    h("span", { class: "mono", testid: "nav-path-id" }, `#${path.id}`),
    ": ",
    h("strong", { testid: "nav-length" }, `${fmt(path.length_m, 2)} m`),
    ` through ${path.points.length - 2} bend(s)`,
    traj
      ? h(
          "span",
          { testid: "nav-duration" },
          `; the projector draws it in ${fmt(traj.duration_s, 1)} s at ${fmt(path.spot_speed_mps, 2)} m/s`,
        )
      : h("span", { class: "small muted" }, "; no projector chosen, nothing to follow"),
    ".",
  );
}

/** Draw a follow run so far into `g`: the robot's trail, the robot (its base radius, a tick
 * for its heading) and the laser spot, at the series' last sample. */
function drawRun(g, series, path, tf) {
  g.replaceChildren();
  if (!series || !series.t || !series.t.length || !series.x) return;
  const k = series.t.length - 1;
  const trail = series.x.map((x, i) => [x, series.y[i]]);
  const [x, y, theta] = [series.x[k], series.y[k], series.theta[k]];
  const radius = path && path.robot_radius_m ? path.robot_radius_m : 0.2;
  g.append(
    s("polyline", {
      class: "plan-trail",
      points: pointsAttr(trail, tf),
      testid: "nav-trail",
      "data-points": trail.length,
    }),
    robotPose(
      { x, y, theta },
      radius,
      tf,
      { testid: "nav-robot", "data-x": x, "data-y": y, "data-theta": theta, "data-t": series.t[k] },
      s("title", null, `robot at ${series.t[k].toFixed(1)} s`),
    ),
    s("circle", {
      class: "plan-spot",
      cx: tf.X(series.spot_x[k]),
      cy: tf.Y(series.spot_y[k]),
      r: 5,
      testid: "nav-spot",
      "data-x": series.spot_x[k],
      "data-y": series.spot_y[k],
    }),
  );
}

/** Draw the planned path (and the beam's spot path, with a projector) into `g`. */
function drawPath(g, path, tf) {
  g.replaceChildren();
  if (!path) return;
  if (path.trajectory) {
    g.append(
      s("polyline", { class: "nav-spot-path", points: pointsAttr(path.trajectory.spot, tf) }),
    );
  }
  g.append(
    s("polyline", {
      class: "nav-path",
      points: pointsAttr(path.points, tf),
      testid: "nav-path",
      "data-points": path.points.length,
    }),
  );
}

/** Draw the start and goal marks into `g`. */
function drawMarks(g, start, goal, tf) {
  g.replaceChildren();
  for (const [p, cls, label] of [
    [start, "nav-start", "start"],
    [goal, "nav-goal", "goal"],
  ]) {
    if (p)
      g.append(
        s("circle", { class: cls, cx: tf.X(p[0]), cy: tf.Y(p[1]), r: 7, testid: `nav-${label}` }),
      );
  }
}

/**
 * The plan of `drawing` in space `spaceId`: clicks set a start and a goal and plan the path
 * with the projector `projectorId()` names (null: none). `onPath(path | null)` is told of each
 * new path (null: a new start, no path yet). Returns {element, hint, summary, drawRun(series,
 * path)}.
 */
export function planView(drawing, spaceId, { projectorId, onPath }) {
  const { tf, svg, g } = planDrawing(drawing);
  const hint = h("p", { class: "small muted", testid: "nav-hint" }, "Click the start on the plan.");
  const summary = h("div", { testid: "nav-summary" });
  let start = null;
  let goal = null;

  const plan = async () => {
    const body = { space_id: spaceId, start, goal };
    const projector = projectorId();
    if (projector !== null) body.projector_id = projector;
    hint.textContent = "Planning…";
    let path;
    try {
      path = await api("/paths", { method: "POST", json: body });
    } catch (err) {
      hint.textContent = "Click a new start.";
      mount(
        summary,
        h("p", { class: "small badge bad", testid: "nav-error" }, err.detail || err.message),
      );
      drawPath(g.path, null, tf);
      g.run.replaceChildren();
      onPath(null);
      return;
    }
    hint.textContent = "Click a new start to plan another path.";
    mount(summary, pathSummary(path));
    drawPath(g.path, path, tf);
    g.run.replaceChildren();
    onPath(path);
  };

  svg.addEventListener("click", (ev) => {
    const w = eventToWorld(svg, tf, ev);
    if (!w) return;
    if (!start || goal) {
      start = w;
      goal = null;
      mount(summary);
      hint.textContent = `Start (${fmt(w[0], 2)}, ${fmt(w[1], 2)}) m; click the goal.`;
      drawPath(g.path, null, tf);
      g.run.replaceChildren();
      drawMarks(g.marks, start, goal, tf);
      onPath(null);
      return;
    }
    goal = w;
    drawMarks(g.marks, start, goal, tf);
    plan();
  });

  return {
    element: h("div", { class: "nav-map" }, svg),
    hint,
    summary,
    drawRun: (series, path) => drawRun(g.run, series, path, tf),
  };
}
