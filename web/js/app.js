// The dashboard's entry point: the hash router, the space picker, the service's health badge;
// the header's sign-in is signin.js.

import { api, chooseSpace, loadSession, leavePage, loadSpaces, poll } from "./api.js";
import { choice } from "./forms.js";
import { renderAuth } from "./signin.js";
import { errorBox, h, mount, s } from "./ui.js";
import { renderOverview } from "./pages/overview.js";
import { renderCameras } from "./pages/cameras.js";
import { renderCamera } from "./pages/cameras/camera.js";
import { renderCalibration } from "./pages/calibration.js";
import { renderRun } from "./pages/calibration/run.js";
import { renderScene } from "./pages/scene.js";
import { renderFloor } from "./pages/floor.js";
import { renderLandmarks } from "./pages/landmarks.js";
import { renderNavigation } from "./pages/navigation.js";
import { renderManipulation } from "./pages/manipulation.js";

// Routes: [pattern, nav section, page title, render(main, params, query) -> cleanup?]
const ROUTES = [
  [/^\/overview$/, "overview", "Overview", renderOverview],
  [/^\/cameras$/, "cameras", "Cameras", renderCameras],
  [/^\/cameras\/(\d+)$/, "cameras", "Camera", renderCamera],
  [/^\/floor$/, "floor", "Floor", renderFloor],
  [/^\/landmarks$/, "landmarks", "Landmarks", renderLandmarks],
  [/^\/navigation$/, "navigation", "Navigation", renderNavigation],
  [/^\/manipulation$/, "manipulation", "Manipulation", renderManipulation],
  [/^\/calibration$/, "calibration", "Calibration runs", renderCalibration],
  [/^\/calibration\/runs\/(\d+)$/, "calibration", "Calibration run", renderRun],
  [/^\/scene$/, "scene", "Live 3D scene", renderScene],
];

const ICONS = {
  overview: "M3 13h8V3H3zm0 8h8v-6H3zm10 0h8V11h-8zm0-18v6h8V3z",
  cameras:
    "M4 7h3l2-3h6l2 3h3a1 1 0 0 1 1 1v11a1 1 0 0 1-1 1H4a1 1 0 0 1-1-1V8a1 1 0 0 1 1-1zm8 11a4.5 4.5 0 1 0 0-9 4.5 4.5 0 0 0 0 9z",
  floor: "M3 4h18v16H3zM11 4v6M11 14v6M3 12h8M15 12h6",
  landmarks: "M4 4h16v16H4zM8 8h3v3H8zM13 8h3v3h-3zM8 13h3v3H8zM13 13h3v3h-3z",
  navigation: "M5 19c3-1 4-5 7-7s6-2 7-7M5 19a1.5 1.5 0 1 0 0 .01M19 5a1.5 1.5 0 1 0 0 .01",
  manipulation: "M4 20h8M8 20v-5l5-6 4 3M13 9l-2-4M17 12l3-3M17 12l2 4",
  calibration: "M3 3h18v18H3zM3 9h18M3 15h18M9 3v18M15 3v18",
  scene: "M12 2 3 7v10l9 5 9-5V7zm0 0v10m0 0 9-5m-9 5-9-5m9 5v10",
};

let cleanup = null;
let renderSeq = 0;

function parseHash() {
  const raw = location.hash.replace(/^#/, "") || "/overview";
  const [path, qs] = raw.split("?");
  return { path, query: new URLSearchParams(qs || "") };
}

async function route() {
  const seq = ++renderSeq;
  if (typeof cleanup === "function") cleanup();
  cleanup = null;
  leavePage();
  const { path, query } = parseHash();
  const main = document.getElementById("main");
  const title = document.getElementById("page-title");
  const match = ROUTES.map(([re, ...rest]) => [path.match(re), ...rest]).find(([m]) => m);
  for (const a of document.querySelectorAll(".nav a")) {
    if (match && a.dataset.route === match[1]) a.setAttribute("aria-current", "page");
    else a.removeAttribute("aria-current");
  }
  if (!match) {
    title.textContent = "Not found";
    document.title = "Not found · intspace";
    mount(main, errorBox({ title: "No such page", detail: `Nothing lives at #${path}.` }));
    return;
  }
  const [m, , pageTitle, render] = match;
  title.textContent = pageTitle;
  document.title = `${pageTitle} · intspace`;
  main.setAttribute("aria-busy", "true");
  mount(main, h("p", { class: "muted", testid: "loading" }, "Loading…"));
  // The spaces are read again on every page, so one created meanwhile can be picked.
  renderSpacePicker(await loadSpaces());
  if (seq !== renderSeq) return;
  // Each render draws into its own detached view, shown only if it is still the current one:
  // a slow page finishing after the user moved on must not overwrite the newer page.
  const view = h("div", { class: "view" });
  try {
    const result = await render(view, m.slice(1), query, (t) => {
      if (seq !== renderSeq) return;
      title.textContent = t;
      document.title = `${t} · intspace`;
    });
    if (seq === renderSeq) {
      main.replaceChildren(view);
      cleanup = result || null;
      // After a navigation (not the first load), move focus to the new page's heading so
      // screen readers announce it.
      if (window.intspaceReadyAt !== undefined) title.focus({ preventScroll: true });
    } else if (typeof result === "function") {
      result(); // navigated away while loading: stop its polling
    }
  } catch (err) {
    if (seq === renderSeq) mount(main, errorBox(err, "page-error"));
  } finally {
    if (seq === renderSeq) {
      main.setAttribute("aria-busy", "false");
      // First time the page is usable (rendered, sign-in field live): measured by the tests.
      if (window.intspaceReadyAt === undefined) window.intspaceReadyAt = performance.now();
      document.documentElement.dataset.ready = "true";
    }
  }
}

/** The header's space picker: every page shows the space chosen here (remembered per browser). */
function renderSpacePicker({ spaces, space }) {
  const box = document.getElementById("space-picker");
  if (!spaces.length) {
    mount(box);
    return;
  }
  const select = choice(
    {
      id: "space-select",
      testid: "space-picker",
      disabled: spaces.length < 2,
      title: spaces.length < 2 ? "The only space" : "Show another space",
      onChange: (ev) => chooseSpace(ev.currentTarget.value),
    },
    spaces.map((sp) => [sp.id, sp.name]),
    space?.id,
  );
  mount(box, h("label", { for: "space-select", class: "small muted" }, "Space"), select);
}

/** Show the service's health in the sidebar, read again every 15 s on every page. */
function followServiceHealth() {
  const dot = document.getElementById("service-dot");
  const text = document.getElementById("service-text");
  poll(() => api("/health"), {
    interval: 15_000,
    maxInterval: 15_000,
    keep: true,
    onValue: (health) => {
      const ok = health.status === "ok";
      dot.className = `dot ${ok ? "ok" : "bad"}`;
      text.textContent = `Service ${health.status}${health.version ? ` · v${health.version}` : ""}`;
      text.title = "";
    },
    onError: (err) => {
      dot.className = "dot bad";
      text.textContent = `Service unreachable`;
      text.title = err.message;
    },
  });
}

function decorateNav() {
  for (const a of document.querySelectorAll(".nav a")) {
    const d = ICONS[a.dataset.route];
    if (!d) continue;
    a.prepend(s("svg", { viewBox: "0 0 24 24", "aria-hidden": "true" }, s("path", { d })));
  }
}

window.addEventListener("hashchange", route);
window.addEventListener("space-changed", route);
window.addEventListener("auth-changed", () => {
  renderAuth();
  route();
});
window.addEventListener("auth-required", (ev) => {
  // A session the service no longer accepts (expired, signed out elsewhere, its token
  // revoked): the header stops claiming a sign-in that no longer holds.
  if (ev.detail?.wasSignedIn) renderAuth("Session ended; sign in again");
  const input = document.getElementById("token-input");
  if (input) input.focus();
});

decorateNav();
// Who is signed in is asked while the first page loads (its reads carry the cookie anyway).
loadSession().then(() => renderAuth());
followServiceHealth();
route();
