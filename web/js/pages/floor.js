// Floor: the chosen space's plan seen from above with the coverage heat map under it, the live
// positions of its robot and people (2-sigma covariance ellipses, tracks) and, in the twin's
// home, the digital twin's controls. This module lays the page out; floor/coverage.js,
// floor/targets.js and floor/twin.js each hold one of its parts.

import { api, currentSpace, inSpace, list, poll } from "../api.js";
import {
  drawCameras,
  drawRooms,
  drawScaleBar,
  drawZones,
  planSvg,
  planTransform,
} from "../plan.js";
import { h, mount, panel, panelHead, s } from "../ui.js";
import { coverageLayer } from "./floor/coverage.js";
import { liveTargets, targetsOf } from "./floor/targets.js";
import { twinPanel } from "./floor/twin.js";

const ZONES_MS = 1000; // GET /spaces/{id}/zones: live occupancy
const W = 900; // SVG user units across; the height follows the plan's aspect, at least 360

/** Draw the zones of these spaces into `g`, read again every second; return the poll. */
function followZones(g, spaceIds, tf) {
  return poll(() => Promise.all(spaceIds.map((id) => api(`/spaces/${id}/zones`))), {
    interval: ZONES_MS,
    // On a failure the plan stays as it was; the next read tries again.
    onValue: (all) => drawZones(g, all.flat(), tf),
  });
}

async function settle(promise) {
  try {
    return { value: await promise };
  } catch (error) {
    return { error };
  }
}

/** Read what the page shows: rooms, cameras, the twin, the coverage map, the live targets. */
async function readFloor() {
  const [rooms, cameras, twin, coverage, targets] = await Promise.all([
    list(inSpace("/rooms"), { limit: 200 }),
    settle(list(inSpace("/cameras", { unassigned: true }), { limit: 200 })),
    settle(api("/twin")),
    settle(api(inSpace("/maps/coverage?format=json"))),
    settle(api(inSpace("/targets"))),
  ]);
  const cov = coverage.value && Array.isArray(coverage.value.x) ? coverage.value : null;
  return {
    rooms: rooms.items,
    cameras: cameras.value?.items || [],
    twin,
    cov,
    coverageError: coverage.error,
    targets: targetsOf(targets.value),
  };
}

/** The plan's mapping: wide enough for the rooms, the posed cameras, the map and the targets. */
function floorTransform({ rooms, cameras, cov, targets }) {
  const extent = [
    ...rooms.flatMap((r) => r.polygon || []),
    ...cameras
      .filter((c) => Array.isArray(c.T_world_camera))
      .map((c) => [c.T_world_camera[0][3], c.T_world_camera[1][3]]),
  ];
  if (cov) extent.push([cov.x[0], cov.y[0]], [cov.x.at(-1), cov.y.at(-1)]);
  for (const t of targets) if (t.xy) extent.push(t.xy);
  if (!extent.length) extent.push([0, 0], [5, 4]);
  return planTransform(extent, { width: W, minHeight: 360 });
}

/** The plan's SVG with its layers, bottom to top; rooms, cameras and the scale bar drawn. */
function floorDrawing(tf, { rooms, cameras }) {
  const svg = planSvg(tf, {
    className: "plot floormap",
    label: "Floor plan with live positions",
    testid: "floor-map",
  });
  const g = {
    heat: s("g", { class: "heat" }),
    rooms: s("g"),
    zones: s("g", { class: "zones", testid: "floor-zones" }),
    cameras: s("g"),
    history: s("g"),
    tracks: s("g"),
    truth: s("g"),
    ellipses: s("g"),
    targets: s("g"),
  };
  svg.append(...Object.values(g));
  drawRooms(g.rooms, rooms, tf);
  drawCameras(g.cameras, cameras, tf);
  drawScaleBar(svg, tf);
  return { svg, g };
}

/** What the plan's marks mean. */
function floorKey() {
  return h(
    "div",
    { class: "legend floor-key" },
    h("span", { class: "key-robot" }, "Robot (located)"),
    h("span", { class: "key-person" }, "Person (located)"),
    h("span", { class: "key-truth" }, "Twin's ground truth (dashed)"),
    h("span", { class: "key-cam" }, "Camera and its viewing direction"),
  );
}

/** The plan's panel: head (clock, source), the drawing, its key, the history toggle and the
 * coverage controls under it. */
function planPanel(svg, live, coverage) {
  return panel(
    null,
    null,
    panelHead(
      "Live positions on the plan",
      "Located by the camera network; tracks and 2σ covariance ellipses",
      h("div", { class: "form-actions", style: { marginTop: 0 } }, live.clock, live.badge),
    ),
    h("div", { class: "floor-wrap" }, svg),
    h("div", { class: "floor-foot" }, floorKey(), live.scaleNote),
    h(
      "div",
      { class: "floor-foot" },
      h(
        "label",
        { class: "small inline" },
        live.history.toggle,
        "show ended targets (last 10 min)",
      ),
      live.history.note,
    ),
    h("div", { class: "floor-foot" }, coverage.controls, coverage.legend, coverage.readout),
    coverage.note,
  );
}

export async function renderFloor(main) {
  const space = currentSpace();
  const floor = await readFloor();
  const tf = floorTransform(floor);
  const { svg, g } = floorDrawing(tf, floor);
  const spaceIds = [...new Set(floor.rooms.map((r) => r.space_id))];
  const zones = followZones(g.zones, spaceIds, tf);
  const coverage = coverageLayer(floor.cov, floor.coverageError, {
    svg,
    gHeat: g.heat,
    tf,
    cameras: floor.cameras,
  });
  const live = await liveTargets(space, tf, g, floor.targets);
  const twin = twinPanel(space, floor.twin, { gTruth: g.truth, tf, onReset: live.clearTracks });
  mount(
    main,
    h(
      "div",
      { class: "grid wide-left" },
      planPanel(svg, live, coverage),
      h(
        "div",
        { class: "grid", style: { alignContent: "start" } },
        panel("Digital twin", "The simulated home: clock and controls", twin.box),
        panel(
          "Targets",
          "Latest position of each target; sd: one standard deviation along the worst direction",
          live.table,
        ),
      ),
    ),
  );
  return () => {
    zones.stop();
    live.stop();
    twin.stop();
  };
}
