// The camera page's "Place" panel: click a point on the camera's latest image, then the same
// point on the floor plan; from 4 pairs on the service fits the camera's pose (and focal
// length when it has no intrinsics) and every pair's residual is drawn on both; apply the fit.

import { api, list } from "../../api.js";
import { sending } from "../../forms.js";
import { drawRooms, eventToWorld, planSvg, planTransform } from "../../plan.js";
import { errorBox, facts, fmt, h, mount, panel, s, table, toast } from "../../ui.js";
import { cameraFrame } from "./live.js";

const PLAN_W = 560;
// Residual arrows are drawn this many times longer than they are, so a pixel shows.
const ARROW_GAIN = 5;

/** The pixel (u, v) under a mouse event on the image's overlay (viewBox in pixel edges:
 * pixel centres at +0.5), or null when the overlay is not laid out. */
function eventToPixel(svg, ev) {
  const m = svg.getScreenCTM();
  if (!m) return null;
  const p = new DOMPoint(ev.clientX, ev.clientY).matrixTransform(m.inverse());
  return [p.x - 0.5, p.y - 0.5];
}

/** The camera's latest image under an SVG overlay the pairs are drawn on; load() reads the
 * image again. Returns {overlay, marks (the overlay's group for the pairs), status, load}. */
function imageView(cam) {
  const image = s("image", { x: 0, y: 0, width: cam.width, height: cam.height });
  const marks = s("g");
  const overlay = s(
    "svg",
    {
      class: "plot place-image",
      viewBox: `0 0 ${cam.width} ${cam.height}`,
      role: "img",
      "aria-label": "The camera's latest image: click a floor point",
      testid: "place-image",
    },
    image,
    marks,
  );
  const status = h("span", { class: "small muted", testid: "place-image-status" });
  async function load() {
    let frame;
    try {
      frame = await cameraFrame(cam.id);
    } catch (err) {
      status.textContent =
        err.status === undefined
          ? err.message
          : "No image of this camera yet: run `intspace node` on it (it sends one a second).";
      return;
    }
    const reader = new FileReader();
    reader.onload = () => {
      image.setAttribute("href", reader.result);
      overlay.dataset.loaded = "1";
      status.textContent = `Image of ${new Date().toLocaleTimeString()}`;
    };
    reader.readAsDataURL(frame.blob);
  }
  return { overlay, marks, status, load };
}

/** The floor plan with the rooms, the pairs drawn on it in `marks`. Returns {tf, plan, marks}. */
function floorView(rooms) {
  const extent = rooms.flatMap((r) => r.polygon || []);
  if (!extent.length) extent.push([0, 0], [10, 8]);
  const tf = planTransform(extent, { width: PLAN_W, minHeight: 300 });
  const gRooms = s("g");
  const marks = s("g");
  const plan = planSvg(
    tf,
    {
      className: "plot floormap place-floor",
      label: "Floor plan: click the same point",
      testid: "place-floor",
    },
    gRooms,
    marks,
  );
  drawRooms(gRooms, rooms, tf);
  return { tf, plan, marks };
}

/** Draw the pairs on the image (`gImage`, with the fit's residual arrows) and on the plan
 * (`gFloor`, with each pair's residual and the fitted camera). */
function drawPairs(gImage, gFloor, { pairs, fit }, cam, tf) {
  const complete = pairs.filter((p) => p.floor);
  const rejected = new Set(fit?.rejected || []);
  gImage.replaceChildren();
  gFloor.replaceChildren();
  const r = Math.max(cam.width, cam.height) / 160;
  pairs.forEach((p, i) => {
    const k = complete.indexOf(p);
    const bad = k >= 0 && rejected.has(k);
    const cls = `place-point${bad ? " rejected" : ""}`;
    const [u, v] = [p.pixel[0] + 0.5, p.pixel[1] + 0.5];
    gImage.append(s("circle", { class: cls, cx: u, cy: v, r }));
    gImage.append(s("text", { class: "place-label", x: u + 1.5 * r, y: v - r }, String(i + 1)));
    if (fit && k >= 0 && fit.residuals[k]) {
      const [du, dv] = fit.residuals[k];
      const arrow = { x1: u, y1: v, x2: u + ARROW_GAIN * du, y2: v + ARROW_GAIN * dv };
      gImage.append(
        s("line", {
          class: `place-residual${bad ? " rejected" : ""}`,
          ...arrow,
          testid: `place-residual-image-${k}`,
        }),
      );
    }
    if (p.floor) {
      const [x, y] = [tf.X(p.floor[0]), tf.Y(p.floor[1])];
      gFloor.append(s("circle", { class: cls, cx: x, cy: y, r: 5 }));
      const label = fit && k >= 0 ? `${i + 1} · ${fmt(fit.residuals_px[k], 1)} px` : String(i + 1);
      gFloor.append(
        s(
          "text",
          { class: "place-label", x: x + 7, y: y - 6, testid: `place-residual-floor-${k}` },
          label,
        ),
      );
    }
  });
  if (fit) {
    const T = fit.T_world_camera;
    gFloor.append(
      s("circle", {
        class: "place-camera",
        cx: tf.X(T[0][3]),
        cy: tf.Y(T[1][3]),
        r: 6,
        testid: "place-camera",
      }),
    );
  }
}

/** The table of the complete pairs with their residuals; `onRemove(pair)` drops one. */
function pairsTable({ pairs, fit }, onRemove) {
  const complete = pairs.filter((p) => p.floor);
  if (!complete.length) return null;
  const rejected = new Set(fit?.rejected || []);
  const remove = (p, k) =>
    h(
      "button",
      {
        class: "btn small",
        type: "button",
        testid: `place-remove-${k}`,
        onClick: () => onRemove(p),
      },
      "Remove",
    );
  const row = (p, k) =>
    h(
      "tr",
      { class: rejected.has(k) ? "rejected" : null },
      h("td", null, String(pairs.indexOf(p) + 1)),
      h("td", { class: "num" }, `${fmt(p.pixel[0], 1)}, ${fmt(p.pixel[1], 1)}`),
      h("td", { class: "num" }, `${fmt(p.floor[0], 2)}, ${fmt(p.floor[1], 2)}`),
      h(
        "td",
        { class: "num", testid: `place-residual-${k}` },
        fit ? fmt(fit.residuals_px[k], 2) + (rejected.has(k) ? " (left out)" : "") : "–",
      ),
      h("td", null, remove(p, k)),
    );
  const head = ["#", "Pixel", "Floor (m)", "Residual (px)", ""];
  return table({ testid: "place-pairs" }, head, complete.map(row));
}

/** The fit's position (± its standard deviations), focal length, RMS and the pairs left out. */
function fitFacts(fit) {
  const { std, T_world_camera: T } = fit;
  return facts({ testid: "place-facts" }, [
    [
      "Position",
      `${fmt(T[0][3], 3)}, ${fmt(T[1][3], 3)}, ${fmt(T[2][3], 3)} m ` +
        `(± ${std.position_m.map((v) => fmt(v, 3)).join(", ")})`,
      { class: "num" },
    ],
    [
      "Focal length",
      `${fmt(fit.K[0][0], 1)} px` + (std.f_px != null ? ` ± ${fmt(std.f_px, 1)}` : " (known)"),
      { class: "num", testid: "place-focal" },
    ],
    ["RMS", `${fmt(fit.rms, 2)} px`, { class: "num", testid: "place-rms" }],
    [
      "Left out",
      fit.rejected.length ? fit.rejected.map((k) => k + 1).join(", ") : "none",
      { testid: "place-rejected" },
    ],
  ]);
}

export async function placePanel(cam, onApplied) {
  const rooms = await list("/rooms", { limit: 200 }).catch(() => ({ items: [] }));
  const { tf, plan, marks: gFloor } = floorView(rooms.items);
  const view = imageView(cam);
  const state = { pairs: [], fit: null }; // pairs: {pixel: [u, v], floor: [x, y] | null}
  let pending = 0;

  const hint = h("p", { class: "small muted", testid: "place-hint" });
  const table = h("div", { class: "table-wrap" });
  const result = h("div", { testid: "place-result" });
  const applyButton = h(
    "button",
    { class: "btn primary", type: "button", testid: "place-apply", disabled: true },
    "Apply",
  );

  function draw() {
    const { pairs } = state;
    drawPairs(view.marks, gFloor, state, cam, tf);
    const complete = pairs.filter((p) => p.floor).length;
    hint.textContent =
      pairs.length && !pairs.at(-1).floor
        ? `Now click point ${pairs.length} on the floor plan.`
        : `Click a point of the floor on the image (${complete} pair(s); 4 or more place the camera).`;
    mount(
      table,
      pairsTable(state, (p) => {
        pairs.splice(pairs.indexOf(p), 1);
        refit();
      }),
    );
  }

  // Every change of the pairs fits again; an answer to an older change is dropped.
  async function refit() {
    const complete = state.pairs.filter((p) => p.floor);
    state.fit = null;
    applyButton.disabled = true;
    mount(result);
    draw();
    if (complete.length < 4) return;
    const mine = ++pending;
    try {
      const answer = await api(`/cameras/${cam.id}/placement`, {
        method: "POST",
        json: { points: complete.map((p) => ({ pixel: p.pixel, floor: p.floor })), apply: false },
      });
      if (mine !== pending) return;
      state.fit = answer;
      applyButton.disabled = false;
      mount(result, fitFacts(answer));
    } catch (err) {
      if (mine !== pending) return;
      mount(result, errorBox(err, "place-error"));
    }
    draw();
  }

  view.overlay.addEventListener("click", (ev) => {
    const px = eventToPixel(view.overlay, ev);
    if (!px) return;
    const { pairs } = state;
    if (pairs.length && !pairs.at(-1).floor) pairs.at(-1).pixel = px;
    else pairs.push({ pixel: px, floor: null });
    draw();
  });
  plan.addEventListener("click", (ev) => {
    const w = eventToWorld(plan, tf, ev);
    const { pairs } = state;
    if (!w || !pairs.length || pairs.at(-1).floor) return;
    pairs.at(-1).floor = w;
    refit();
  });
  applyButton.addEventListener(
    "click",
    sending(applyButton, async () => {
      if (!state.fit) return;
      await api(`/calibration-runs/${state.fit.run_id}/apply`, { method: "POST" });
      toast(`Camera “${cam.name}” placed`);
      onApplied();
    }),
  );

  draw();
  view.load();
  return placeLayout(view, plan, hint, table, result, applyButton);
}

/** The panel: the hint, the image beside the plan, the pairs, the fit and its Apply button. */
function placeLayout(view, plan, hint, table, result, applyButton) {
  return panel(
    "Place",
    "Click a point of the floor on the image, then the same point on the plan; from 4 pairs the " +
      "camera is fitted (wrong pairs are left out from 6), residuals drawn ×" +
      ARROW_GAIN,
    hint,
    h(
      "div",
      { class: "grid two" },
      h(
        "div",
        null,
        view.overlay,
        h(
          "div",
          { class: "form-actions" },
          view.status,
          h("button", { class: "btn small", type: "button", onClick: view.load }, "New image"),
        ),
      ),
      h("div", { class: "floor-wrap" }, plan),
    ),
    table,
    result,
    h("div", { class: "form-actions" }, applyButton),
  );
}
