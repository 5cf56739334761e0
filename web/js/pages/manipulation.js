// Manipulation: the robots' arms, hand-eye calibration of an arm's eye-in-hand camera (a run
// on the twin, its result against the twin's truth, applied to the arm), and fetch tasks on
// the twin with their phases and episode metrics as they run.

import { inSpace, list } from "../api.js";
import { h, mount, panel } from "../ui.js";
import { addArmForm, armTable } from "./manipulation/arms.js";
import { handEyePanel } from "./manipulation/handeye.js";
import { tasksPanel } from "./manipulation/tasks.js";

export async function renderManipulation(main) {
  const stops = {};
  const draw = async () => {
    const [allArms, robots, tasks] = await Promise.all([
      list("/arms", { limit: 200 }),
      list(inSpace("/robots", { unassigned: true }), { limit: 200 }),
      list("/tasks", { limit: 10 }),
    ]);
    // The arms of the space's robots (and of robots in no space).
    const robotIds = new Set(robots.items.map((r) => r.id));
    const arms = { ...allArms, items: allArms.items.filter((a) => robotIds.has(a.robot_id)) };
    const armsBox = h("div", { testid: "arms" }, armTable(arms.items, robots.items));
    const refreshArms = async () => {
      const fresh = (await list("/arms", { limit: 200 })).items.filter((a) =>
        robotIds.has(a.robot_id),
      );
      if (fresh.length !== arms.items.length) return draw();
      mount(armsBox, armTable(fresh, robots.items));
    };
    for (const stop of Object.values(stops)) stop?.();
    mount(
      main,
      panel(
        "Arms",
        "The robots' arms: Denavit-Hartenberg model, joint limits, eye-in-hand camera and its " +
          "hand-eye transform",
        armsBox,
        addArmForm(robots.items, draw),
      ),
      handEyePanel(arms.items, stops, refreshArms),
      tasksPanel(arms.items, tasks.items, stops),
    );
  };
  await draw();
  return () => {
    for (const stop of Object.values(stops)) stop?.();
  };
}
