// The camera page's "Place" panel: click a point on the camera's latest image, then the same
// point on the floor plan; from 4 pairs on the service fits the camera's pose (and focal
// length when it has no intrinsics) and every pair's residual is drawn on both; apply the fit.

import { api, list } from "../api.js";
import { drawRooms, eventToWorld, planSvg, planTransform } from "../plan.js";
import { errorBox, fmt, h, mount, panel, s, toast, toastError } from "../ui.js";

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

export async function placePanel(cam, onApplied) {
  const rooms = await list("/rooms", { limit: 200 }).catch(() => ({ items: [] }));
  const extent = rooms.items.flatMap((r) => r.polygon || []);
  if (!extent.length) extent.push([0, 0], [10, 8]);
  const tf = planTransform(extent, { width: PLAN_W, minHeight: 300 });

  const pairs = []; // {pixel: [u, v], floor: [x, y] | null}
  let fit = null;
  let pending = 0;

  const image = s("image", { x: 0, y: 0, width: cam.width, height: cam.height });
  const gImage = s("g");
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
    gImage,
  );
  const gRooms = s("g");
  const gFloor = s("g");
  const plan = planSvg(
    tf,
    { className: "plot floormap place-floor", label: "Floor plan: click the same point", testid: "place-floor" },
    gRooms,
    gFloor,
  );
  drawRooms(gRooms, rooms.items, tf);

  const hint = h("p", { class: "small muted", testid: "place-hint" });
  const table = h("div", { class: "table-wrap" });
  const result = h("div", { testid: "place-result" });
  const applyButton = h(
    "button",
    { class: "btn primary", type: "button", testid: "place-apply", disabled: true },
    "Apply",
  );
  const imageStatus = h("span", { class: "small muted", testid: "place-image-status" });

  async function loadImage() {
    try {
      const response = await fetch(`/api/v1/cameras/${cam.id}/frame.jpg`, {
        credentials: "same-origin",
      });
      if (!response.ok) {
        imageStatus.textContent =
          "No image of this camera yet: run `intspace node` on it (it sends one a second).";
        return;
      }
      const blob = await response.blob();
      const reader = new FileReader();
      reader.onload = () => {
        image.setAttribute("href", reader.result);
        overlay.dataset.loaded = "1";
        imageStatus.textContent = `Image of ${new Date().toLocaleTimeString()}`;
      };
      reader.readAsDataURL(blob);
    } catch (err) {
      imageStatus.textContent = `The service did not answer (${err.message}).`;
    }
  }

  function draw() {
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
        gImage.append(
          s("line", {
            class: `place-residual${bad ? " rejected" : ""}`,
            x1: u,
            y1: v,
            x2: u + ARROW_GAIN * du,
            y2: v + ARROW_GAIN * dv,
            testid: `place-residual-image-${k}`,
          }),
        );
      }
      if (p.floor) {
        const [x, y] = [tf.X(p.floor[0]), tf.Y(p.floor[1])];
        gFloor.append(s("circle", { class: cls, cx: x, cy: y, r: 5 }));
        const label = fit && k >= 0 ? `${i + 1} · ${fmt(fit.residuals_px[k], 1)} px` : String(i + 1);
        gFloor.append(
          s("text", { class: "place-label", x: x + 7, y: y - 6, testid: `place-residual-floor-${k}` }, label),
        );
      }
    });
    if (fit) {
      const T = fit.T_world_camera;
      const [cx, cy] = [tf.X(T[0][3]), tf.Y(T[1][3])];
      gFloor.append(s("circle", { class: "place-camera", cx, cy, r: 6, testid: "place-camera" }));
    }
    const waiting = pairs.length && !pairs.at(-1).floor;
    hint.textContent = waiting
      ? `Now click point ${pairs.length} on the floor plan.`
      : `Click a point of the floor on the image (${complete.length} pair(s); 4 or more place the camera).`;
    mount(
      table,
      complete.length
        ? h(
            "table",
            { testid: "place-pairs" },
            h(
              "thead",
              null,
              h("tr", null, ["#", "Pixel", "Floor (m)", "Residual (px)", ""].map((t) => h("th", null, t))),
            ),
            h(
              "tbody",
              null,
              complete.map((p, k) =>
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
                  h(
                    "td",
                    null,
                    h(
                      "button",
                      {
                        class: "btn small",
                        type: "button",
                        testid: `place-remove-${k}`,
                        onClick: () => {
                          pairs.splice(pairs.indexOf(p), 1);
                          refit();
                        },
                      },
                      "Remove",
                    ),
                  ),
                ),
              ),
            ),
          )
        : null,
    );
  }

  async function refit() {
    const complete = pairs.filter((p) => p.floor);
    fit = null;
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
      fit = answer;
      applyButton.disabled = false;
      const std = answer.std;
      const T = answer.T_world_camera;
      mount(
        result,
        h(
          "dl",
          { class: "facts", testid: "place-facts" },
          h("dt", null, "Position"),
          h(
            "dd",
            { class: "num" },
            `${fmt(T[0][3], 3)}, ${fmt(T[1][3], 3)}, ${fmt(T[2][3], 3)} m ` +
              `(± ${std.position_m.map((v) => fmt(v, 3)).join(", ")})`,
          ),
          h("dt", null, "Focal length"),
          h(
            "dd",
            { class: "num", testid: "place-focal" },
            `${fmt(answer.K[0][0], 1)} px` + (std.f_px != null ? ` ± ${fmt(std.f_px, 1)}` : " (known)"),
          ),
          h("dt", null, "RMS"),
          h("dd", { class: "num", testid: "place-rms" }, `${fmt(answer.rms, 2)} px`),
          h("dt", null, "Left out"),
          h(
            "dd",
            { testid: "place-rejected" },
            answer.rejected.length ? answer.rejected.map((k) => k + 1).join(", ") : "none",
          ),
        ),
      );
    } catch (err) {
      if (mine !== pending) return;
      mount(result, errorBox(err, "place-error"));
    }
    draw();
  }

  overlay.addEventListener("click", (ev) => {
    const px = eventToPixel(overlay, ev);
    if (!px) return;
    if (pairs.length && !pairs.at(-1).floor) pairs.at(-1).pixel = px;
    else pairs.push({ pixel: px, floor: null });
    draw();
  });
  plan.addEventListener("click", (ev) => {
    const w = eventToWorld(plan, tf, ev);
    if (!w || !pairs.length || pairs.at(-1).floor) return;
    pairs.at(-1).floor = w;
    refit();
  });
  applyButton.addEventListener("click", async () => {
    if (!fit) return;
    try {
      await api(`/calibration-runs/${fit.run_id}/apply`, { method: "POST" });
      toast(`Camera “${cam.name}” placed`);
      onApplied();
    } catch (err) {
      toastError(err);
    }
  });

  draw();
  loadImage();
  return panel(
    "Place",
    "Click a point of the floor on the image, then the same point on the plan; from 4 pairs the " +
      "camera is fitted (wrong pairs are left out from 6), residuals drawn ×" +
      ARROW_GAIN,
    hint,
    h(
      "div",
      { class: "grid two" },
      h("div", null, overlay, h("div", { class: "form-actions" }, imageStatus,
        h("button", { class: "btn small", type: "button", onClick: loadImage }, "New image"))),
      h("div", { class: "floor-wrap" }, plan),
    ),
    table,
    result,
    h("div", { class: "form-actions" }, applyButton),
  );
}
