// The camera page's live image: the latest frame with its detections drawn, read about twice a
// second while the page is shown.

import { api, poll } from "../../api.js";
import { clockTime, h, mount, panel } from "../../ui.js";

const LIVE_MS = 500; // about 2 frames a second
const LIVE_RETRY_MS = 5000; // when there is no frame (no twin): look again now and then

/**
 * The camera's latest frame with its detections drawn, refreshed about twice a second. The image
 * is fetched (with the session cookie) and shown from a blob URL once decoded, so a frame
 * never flickers in half-loaded. Returns {panel, stop}.
 */
export function liveView(id) {
  const img = h("img", {
    class: "live-frame",
    alt: "Latest frame of this camera with detections drawn",
    testid: "camera-live-image",
    hidden: true,
  });
  const status = h("span", { class: "small muted", testid: "camera-live-status" }, "Loading…");
  const missing = h("div");
  let url = null;
  let frames = 0;
  // A frame decoded from the blob before it is shown, so the image never flickers half-loaded.
  const show = async ({ blob, received }) => {
    const next = URL.createObjectURL(blob);
    await new Promise((resolve) => {
      img.onload = resolve;
      img.onerror = resolve;
      img.src = next;
    });
    if (url) URL.revokeObjectURL(url);
    url = next;
    frames += 1;
    img.hidden = false;
    img.dataset.frames = String(frames);
    mount(missing);
    status.textContent =
      `Refreshed ${new Date().toLocaleTimeString()}` +
      (received ? ` · received at ${clockTime(received)}` : "");
  };
  const frame = () =>
    document.visibilityState === "hidden" ? null : cameraFrame(id, { overlay: true });
  // No frame (no twin, no node yet): look again less and less often, up to LIVE_RETRY_MS.
  const live = poll(frame, {
    interval: LIVE_MS,
    maxInterval: LIVE_RETRY_MS,
    onValue: (got) => (got ? show(got) : undefined),
    onError: (err) => {
      if (err.status === undefined) {
        status.textContent = err.message;
        return;
      }
      img.hidden = true;
      status.textContent = "";
      mount(missing, noImage(err.status, err.detail));
    },
  });
  return {
    panel: panel(
      "Live image",
      "The latest frame with the detections drawn (robot marker, people), about 2 per second",
      img,
      missing,
      h("div", { style: { marginTop: "8px" } }, status),
    ),
    stop: () => {
      live.stop();
      if (url) URL.revokeObjectURL(url);
    },
  };
}

/**
 * Return the camera's latest frame (GET /cameras/{id}/frame.jpg, its detections drawn when
 * `overlay`) as {blob, received}: the JPEG, and when a camera node's frame reached the service
 * (Unix s; null for the twin's renders). Throws ApiError (its detail says why) when there is none.
 */
export async function cameraFrame(id, { overlay = false } = {}) {
  const query = overlay ? "?overlay=true" : "";
  const response = await api(`/cameras/${id}/frame.jpg${query}`, {
    raw: true,
    accept: "image/jpeg",
  });
  const received = response.headers.get("x-frame-received");
  return { blob: await response.blob(), received: received ? Number(received) : null };
}

function noImage(status, reason) {
  return h(
    "p",
    { class: "empty", testid: "camera-live-missing" },
    status === 404 ? "No image yet" : `No image (HTTP ${status})`,
    reason ? `: ${reason}.` : ".",
    status === 404
      ? h(
          "span",
          { class: "small muted", style: { display: "block", marginTop: "6px" } },
          "A camera's latest image is shown once its source delivers one: the digital twin " +
            "for its own cameras, a camera node for the others.",
        )
      : null,
  );
}
