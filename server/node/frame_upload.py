"""A camera node's latest frames for the service: each camera's newest image uploaded at most
once per FRAME_UPLOAD_S (PUT /cameras/{id}/frame), so the dashboard shows a real camera's
view (placing it from floor points needs it). Offering a frame costs the detector nothing but
a reference; encoding and sending happen on the heartbeat thread."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import cv2
import httpx
import numpy as np
from numpy.typing import NDArray

from server.node.client import ServiceClient

log = logging.getLogger("intspace.node")

# The service takes one frame a second per camera; a little more keeps the node's sends clear
# of its limit whatever the network's jitter.
FRAME_UPLOAD_S = 1.1
JPEG_QUALITY = 85


class FrameUploads:
    """The newest frame of each camera, uploaded at most once per `interval_s`."""

    def __init__(self, client: ServiceClient, interval_s: float = FRAME_UPLOAD_S) -> None:
        self._client = client
        self._interval = interval_s
        self._lock = threading.Lock()
        self._newest: dict[int, tuple[NDArray[np.uint8] | None, bytes | None]] = {}
        self._sent: dict[int, float] = {}
        self.uploaded = 0

    def offer(
        self, camera_id: int, image: NDArray[np.uint8] | None = None, jpeg: bytes | None = None
    ) -> None:
        """Keep a camera's newest frame (decoded image or the stream's own JPEG)."""
        with self._lock:
            self._newest[camera_id] = (image, jpeg)

    def send_due(self) -> None:
        """Upload the newest frame of every camera whose last upload is `interval_s` old."""
        now = time.monotonic()
        with self._lock:
            due = {
                cid: frame
                for cid, frame in self._newest.items()
                if now - self._sent.get(cid, -np.inf) >= self._interval
            }
            for cid in due:
                del self._newest[cid]
        for camera_id, (image, jpeg) in due.items():
            if jpeg is None and image is not None:
                ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
                jpeg = buf.tobytes() if ok else None
            if jpeg is None:
                continue
            self._sent[camera_id] = time.monotonic()
            try:
                response = self._client.request(
                    "PUT",
                    f"/cameras/{camera_id}/frame",
                    content=jpeg,
                    headers={"Content-Type": "image/jpeg"},
                )
            except httpx.TransportError:
                continue
            if response.status_code == 204:
                self.uploaded += 1
            elif response.status_code != 429:
                log.warning(
                    "camera %d: frame refused (%d): %s",
                    camera_id,
                    response.status_code,
                    _detail(response),
                )


def _detail(response: httpx.Response) -> Any:
    try:
        return response.json().get("detail")
    except ValueError:
        return response.text[:200]
