// The live 3D scene: the viser viewer, proxied by the service under /api/v1/scene/view/ behind
// the dashboard's sign-in (the session cookie reaches it; viser itself listens on loopback only).

import { api } from "../api.js";
import { h, mount, panel } from "../ui.js";

/** Return the viewer's address as a same-origin path (the iframe must share the cookie). */
export function viewerUrl(reported) {
  const url = new URL(reported, location.href);
  return url.pathname + url.search;
}

export async function renderScene(main) {
  const scene = await api("/scene");
  const url = viewerUrl(scene.viser_url);
  const legend = h(
    "div",
    { class: "legend", "aria-label": "Legend" },
    h("span", { style: { "--swatch": "#2563eb" } }, "Calibrated camera"),
    h("span", { style: { "--swatch": "#d97706" } }, "Pose known, no intrinsics"),
    h("span", { style: { "--swatch": "#94969f" } }, "Uncalibrated pose (parked beside the plan)"),
  );
  mount(
    main,
    panel(
      null,
      null,
      h(
        "div",
        { class: "panel-head" },
        h(
          "div",
          null,
          h("h2", null, "Floor plan and cameras in 3D"),
          h(
            "p",
            null,
            "Drag to orbit, scroll to zoom. Frusta follow calibrations within a second.",
          ),
        ),
        h(
          "a",
          { class: "btn", href: url, target: "_blank", rel: "noopener", testid: "scene-open" },
          "Open in a new tab",
        ),
      ),
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
