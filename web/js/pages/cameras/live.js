// The camera page's live image: the latest frame with its detections drawn, read about twice a
// second while the page is shown.

import { poll } from "../../api.js";
import { h, mount, panel } from "../../ui.js";

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
  const show = async ({ blob, t }) => {
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
      (t ? ` · sim time ${Number(t).toFixed(1)} s` : "");
  };
  const frame = async () => {
    if (document.visibilityState === "hidden") return null;
    const response = await fetch(`/api/v1/cameras/${id}/frame.jpg?overlay=true`, {
      headers: { Accept: "image/jpeg" },
      credentials: "same-origin",
    });
    if (!response.ok) {
      throw Object.assign(new Error("no frame"), {
        status: response.status,
        reason: await reasonOf(response),
      });
    }
    const t = response.headers.get("x-sim-time") || response.headers.get("x-frame-time");
    return { blob: await response.blob(), t };
  };
  // No frame (no twin, no node yet): look again less and less often, up to LIVE_RETRY_MS.
  const live = poll(frame, {
    interval: LIVE_MS,
    maxInterval: LIVE_RETRY_MS,
    onValue: (got) => (got ? show(got) : undefined),
    onError: (err) => {
      if (err.reason === undefined) {
        status.textContent = `The service did not answer (${err.message}).`;
        return;
      }
      img.hidden = true;
      status.textContent = "";
      mount(missing, noImage(err.status, err.reason));
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

/** The service's reason for an answer without an image (its problem detail), or "". */
async function reasonOf(response) {
  try {
    const body = await response.json();
    return typeof body.detail === "string" ? body.detail : "";
  } catch {
    return "";
  }
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
