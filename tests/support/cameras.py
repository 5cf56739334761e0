"""Cameras registered through the API, as a user registers calibrated ones."""

from __future__ import annotations

from typing import Any

import numpy as np

from core.localization import NetworkCamera


def register_cameras(
    client: Any,
    headers: dict[str, str],
    cameras: list[NetworkCamera],
    *,
    prefix: str = "cam",
    url: str = "/api/v1/cameras",
    with_dist: bool = True,
) -> list[int]:
    """POST each camera (named `prefix`0, `prefix`1, ...: its K, distortion, pose and a 640 x 480
    image) to `url` with `client` (a TestClient or an httpx.Client); return their ids. Without
    `with_dist` the distortion is not sent: the camera is registered with none known."""
    ids = []
    for k, cam in enumerate(cameras):
        body = {
            "name": f"{prefix}{k}",
            "width": 640,
            "height": 480,
            "K": np.asarray(cam.K).tolist(),
            "T_world_camera": cam.T_world_camera.tolist(),
        }
        if with_dist:
            body["dist"] = np.ravel(cam.dist).tolist()
        response = client.post(url, json=body, headers=headers)
        assert response.status_code == 201, response.text
        ids.append(response.json()["id"])
    return ids
