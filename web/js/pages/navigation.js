// Navigation: the floor plan paths are planned on (rooms, walls, furniture); click a start and
// a goal to plan a path (POST /paths), drawn by the chosen projector; follow it on the twin
// (POST /paths/{id}/follow) and watch, live, its status, the robot and the spot moving on the
// plan and the tracking error over time. This module lays the page out; navigation/plan.js,
// navigation/follow.js and navigation/projectors.js each hold one of its parts.

import { api, currentSpace, list } from "../api.js";
import { h, infoBox, mount, panel } from "../ui.js";
import { followView } from "./navigation/follow.js";
import { planView } from "./navigation/plan.js";
import { projectorViews } from "./navigation/projectors.js";

export async function renderNavigation(main) {
  const space = currentSpace();
  if (!space) {
    mount(main, infoBox("No space yet: register a space and its rooms first.", "nav-empty"));
    return null;
  }
  const [drawing, projectors] = await Promise.all([
    api(`/paths/floor-plan?space_id=${space.id}`),
    list(`/projectors?space_id=${space.id}`, { limit: 200 }),
  ]);
  const pj = projectorViews(space);
  pj.fill(projectors.items);
  const follow = followView({ drawRun: (series, path) => plan.drawRun(series, path) });
  const plan = planView(drawing, space.id, {
    projectorId: () => (pj.planSelect.value ? Number(pj.planSelect.value) : null),
    onPath: (path) => follow.setPath(path),
  });
  const planBadge = h(
    "span",
    { class: "badge", testid: "nav-floor-plan" },
    `Floor plan: ${drawing.floor_plan}`,
  );

  mount(
    main,
    panel(
      "Plan",
      "Click a start, then a goal: the path keeps the robot's radius plus 5 cm from walls and " +
        "furniture; with a projector, the service also plans the beam's joint trajectory.",
      h("div", { class: "nav-toolbar" }, h("label", null, "Projector ", pj.planSelect), planBadge),
      plan.element,
      plan.hint,
      plan.summary,
    ),
    panel(
      "Projector calibration",
      "The twin's projector points its beam at spots over the floor; the space's calibrated " +
        "ceiling cameras locate each spot and the projector's mount is fitted to them. Apply " +
        "the result to plan with the new mount.",
      pj.calibration.toolbar,
      pj.calibration.why,
      pj.calibration.box,
    ),
    panel(
      "Follow",
      "The twin's robot follows the projected spot with its floor camera (15 Hz, 100 ms " +
        "latency); the error is the distance from its control point to the spot. While it " +
        "runs, the robot (green, with its trail) and the spot (red) move on the plan.",
      follow.toolbar,
      follow.box,
      follow.chart,
    ),
  );
  return () => {
    pj.stop();
    follow.stop();
  };
}
