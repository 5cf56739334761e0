"""The room (tests/support/room.py) watched by three ceiling cameras at its corners and a person
walking in it, as the cameras' nodes would report them: the zones' and the home's tests follow
a person's occupancy of a zone."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from core.localization import NetworkCamera
from tests.support.room import K, ceiling_cameras

# Three corners of the room (tests/support/room.py), 2.8 m up.
CORNERS = ([0.0, 0.0, 2.8], [4.0, 3.0, 2.8], [4.0, 0.0, 2.8])


def corner_cameras() -> list[NetworkCamera]:
    """Return the room's ceiling cameras at CORNERS, with no distortion."""
    return ceiling_cameras(CORNERS, dist=None)


def camera_body(name: str, space_id: int, camera: NetworkCamera) -> dict[str, Any]:
    """Return the body of POST /cameras registering `camera` (a corner camera) in `space_id`."""
    return {
        "name": name,
        "space_id": space_id,
        "width": 640,
        "height": 480,
        "K": K,
        "T_world_camera": camera.T_world_camera.tolist(),
    }


def register_corner_cameras(
    client: Any, headers: dict[str, str], space_id: int, prefix: str
) -> tuple[list[int], list[NetworkCamera]]:
    """POST the corner cameras (named `prefix`0, `prefix`1, ...) with `client` (a TestClient);
    return their ids and the cameras."""
    cams = corner_cameras()
    ids = []
    for k, cam in enumerate(cams):
        body = camera_body(f"{prefix}{k}", space_id, cam)
        response = client.post("/api/v1/cameras", json=body, headers=headers)
        assert response.status_code == 201, response.text
        ids.append(response.json()["id"])
    return ids, cams


def walk(
    client: Any,
    headers: dict[str, str],
    ids: list[int],
    cams: list[NetworkCamera],
    path: list[tuple[float, float]],
    *,
    rate: float = 10.0,
    t0: float | None = None,
    after_each: Callable[[], object] | None = None,
) -> list[float]:
    """Post the cameras' detections of a person (axis point 1 m up, 0.5 px of noise, seed 0)
    along `path` ((x, y) on the floor) at `rate` frames a second in real time, the first
    captured at `t0` (default: now); call `after_each` after each post; return the capture
    times."""
    rng = np.random.default_rng(0)
    t0 = time.time() if t0 is None else t0
    times = []
    for k, (x, y) in enumerate(path):
        t = t0 + k / rate
        X = np.array([[x, y, 1.0]])
        obs = [
            {
                "camera_id": cid,
                "t": t,
                "pixel": (cam.project(X)[0] + rng.normal(0, 0.5, 2)).tolist(),
                "sigma_px": 0.5,
                "kind": "person",
                "height": 1.0,
            }
            for cid, cam in zip(ids, cams, strict=True)
        ]
        response = client.post("/api/v1/observations", json={"observations": obs}, headers=headers)
        assert response.status_code == 200, response.text
        times.append(t)
        if after_each is not None:
            after_each()
        # Time must pass between the frames: a person walks at the pace of the capture times.
        time.sleep(max(0.0, t0 + (k + 1) / rate - time.time()))
    return times
