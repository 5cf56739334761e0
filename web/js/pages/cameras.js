// Cameras: the chosen space's table of cameras, with a form that adds one. One camera's page is
// cameras/camera.js.

import { api, currentSpace, inSpace, list } from "../api.js";
import { errorSlot, field, sending } from "../forms.js";
import { badge, fmt, h, linkRow, mount, panel, table, toast, when } from "../ui.js";
import { healthBadge } from "./cameras/health.js";

/** Return a camera's status: the service's, else whether it has intrinsics. */
export function cameraStatus(c) {
  return c.status || (c.K ? "calibrated" : "uncalibrated");
}

/** Count cameras as the table shows them: calibrated (Status) and online (Health). */
export function cameraCounts(cameras) {
  return {
    calibrated: cameras.filter((c) => cameraStatus(c) === "calibrated").length,
    online: cameras.filter((c) => c.health?.status === "online").length,
  };
}

function addCameraForm(space, onCreated) {
  const error = errorSlot();
  const name = h("input", {
    id: "cam-name",
    name: "name",
    required: true,
    maxlength: 200,
    placeholder: "e.g. ceiling-kitchen",
    testid: "camera-name",
  });
  const size = (id, value) =>
    h("input", {
      id: `cam-${id}`,
      name: id,
      type: "number",
      min: 1,
      required: true,
      value,
      testid: `camera-${id}`,
    });
  const width = size("width", "1280");
  const height = size("height", "720");
  const submit = h(
    "button",
    { class: "btn primary", type: "submit", testid: "camera-create" },
    "Add camera",
  );
  const form = h(
    "form",
    {
      testid: "camera-form",
      onSubmit: sending(
        submit,
        async () => {
          const cam = await api("/cameras", {
            method: "POST",
            json: {
              name: name.value.trim(),
              width: Number(width.value),
              height: Number(height.value),
              space_id: space ? space.id : null,
            },
          });
          toast(`Camera “${cam.name}” added`);
          form.reset();
          onCreated(cam);
        },
        { errors: error, testid: "camera-form-error" },
      ),
    },
    h(
      "div",
      { class: "form-grid" },
      field("cam-name", "Name", name),
      field("cam-width", "Image width (px)", width),
      field("cam-height", "Image height (px)", height),
      h("div", null, submit),
    ),
    error,
  );
  return form;
}

/** The space's cameras, one row each (a click opens the camera's page). */
function camerasTable(items, space) {
  const head = ["Name", "Image", "Status", "Health", "fx", "fy", "cx", "cy", "Pose", "Updated"];
  const columns = head.map((t, i) => [t, { class: i >= 4 && i <= 7 ? "num" : null, scope: "col" }]);
  const row = (c) =>
    linkRow(
      `#/cameras/${c.id}`,
      { testid: `camera-row-${c.id}` },
      h(
        "td",
        null,
        h("a", { href: `#/cameras/${c.id}` }, c.name),
        space && c.space_id === null
          ? h("span", { class: "small muted", testid: `camera-no-space-${c.id}` }, " (no space)")
          : null,
      ),
      h("td", { class: "num" }, `${c.width} × ${c.height}`),
      h("td", null, badge(cameraStatus(c))),
      h(
        "td",
        { title: c.health?.fps ? `${fmt(c.health.fps, 1)} frames/s` : null },
        healthBadge(c.health, `camera-health-${c.id}`),
      ),
      [0, 4, 2, 5].map((k) =>
        h("td", { class: "num" }, c.K ? fmt(c.K[Math.floor(k / 3)][k % 3], 2) : "–"),
      ),
      h("td", null, c.T_world_camera ? "calibrated" : h("span", { class: "muted" }, "unknown")),
      h("td", { class: "small muted" }, when(c.updated_at)),
    );
  return table({ testid: "camera-table" }, columns, items.map(row));
}

export async function renderCameras(main) {
  const space = currentSpace();
  const { items, total } = await list(inSpace("/cameras", { unassigned: true }), { limit: 200 });
  const table = camerasTable(items, space);
  mount(
    main,
    panel(
      "Add a camera",
      space
        ? `Register a camera of ${space.name} by name and image size; calibrate it afterwards`
        : "Register a camera by name and image size; calibrate it afterwards",
      addCameraForm(space, (cam) => {
        location.hash = `#/cameras/${cam.id}`;
      }),
    ),
    panel(
      space ? `Cameras of ${space.name} (${total})` : `Cameras (${total})`,
      "Click a camera for its health, latest image, intrinsics, calibration history and exports",
      items.length
        ? h(
            "div",
            { class: "table-wrap" },
            table,
            total > items.length
              ? h("p", { class: "small muted" }, `Showing the first ${items.length} of ${total}.`)
              : null,
          )
        : h(
            "p",
            { class: "empty", testid: "camera-table-empty" },
            space
              ? `No cameras in ${space.name} yet. Add one above.`
              : "No cameras yet. Add one above.",
          ),
    ),
  );
}
