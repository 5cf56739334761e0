// The live 3D scene: the viser viewer, proxied by the service under /api/v1/scene/view/ behind
// the dashboard's sign-in (the session cookie reaches it; viser itself listens on loopback only).
// The scene shows one space at a time: the one picked in the header, which the page asks the
// service to show (PUT /scene) when it shows another.

import { api, currentSession, currentSpace, spaceById } from "../api.js";
import { cssVar } from "../colours.js";
import { h, infoBox, mount, panel, panelHead } from "../ui.js";

/** Return the viewer's address as a same-origin path (the iframe must share the cookie). */
export function viewerUrl(reported) {
  const url = new URL(reported, location.href);
  return url.pathname + url.search;
}

/** Return the scene's link after making it show the chosen space where it can, and a note
 * when it shows another. */
async function sceneOfSpace() {
  let scene = await api("/scene");
  const space = currentSpace();
  if (!space || scene.space_id === null || scene.space_id === space.id) return { scene };
  if ((currentSession().scopes || []).some((sc) => sc === "write" || sc === "admin")) {
    try {
      scene = await api("/scene", { method: "PUT", json: { space_id: space.id } });
      return { scene };
    } catch (err) {
      return { scene, note: `The scene could not be switched to ${space.name}: ${err.message}` };
    }
  }
  const shown = spaceById(scene.space_id)?.name || `space ${scene.space_id}`;
  return {
    scene,
    note: `The scene shows ${shown}, not ${space.name}: switching it takes a token with the write scope.`,
  };
}

export async function renderScene(main) {
  const { scene, note } = await sceneOfSpace();
  const url = viewerUrl(scene.viser_url);
  const shown = scene.space_id ? spaceById(scene.space_id)?.name : null;
  const legend = h(
    "div",
    { class: "legend", "aria-label": "Legend" },
    h("span", { style: { "--swatch": cssVar("brand-2") } }, "Calibrated camera"),
    h("span", { style: { "--swatch": cssVar("amber-600") } }, "Pose known, no intrinsics"),
    h("span", { style: { "--swatch": cssVar("scene-parked") } }, "Uncalibrated pose (parked beside the plan)"),
  );
  mount(
    main,
    panel(
      null,
      null,
      panelHead(
        h(
          "h2",
          { testid: "scene-space", "data-space-id": scene.space_id ?? "" },
          shown ? `${shown} in 3D` : "Floor plan and cameras in 3D",
        ),
        "Drag to orbit, scroll to zoom. Frusta follow calibrations within a second.",
        h(
          "a",
          { class: "btn", href: url, target: "_blank", rel: "noopener", testid: "scene-open" },
          "Open in a new tab",
        ),
      ),
      note ? infoBox(note, "scene-note") : null,
      h("iframe", {
        class: "scene-frame",
        src: url,
        title: "Live 3D scene of the space",
        testid: "scene-iframe",
        allow: "fullscreen",
      }),
      h("div", { style: { marginTop: "12px" } }, legend),
    ),
  );
}
