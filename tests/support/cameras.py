"""Cameras registered through the API, as a user registers calibrated ones."""

from __future__ import annotations

from typing import Any

import numpy as np

from core.localization import NetworkCamera


def register_cameras(
    client: Any, headers: dict[str, str], cameras: list[NetworkCamera]
) -> list[int]:
    """POST each camera (named cam0, cam1, ...: its K, distortion, pose and a 640 x 480 image)
    to /api/v1/cameras with `client` (a TestClient or an httpx.Client); return their ids."""
    ids = []
    for k, cam in enumerate(cameras):
        body = {
            "name": f"cam{k}",
            "width": 640,
            "height": 480,
            "K": np.asarray(cam.K).tolist(),
            "dist": np.ravel(cam.dist).tolist(),
            "T_world_camera": cam.T_world_camera.tolist(),
        }
        response = client.post("/api/v1/cameras", json=body, headers=headers)
        assert response.status_code == 201, response.text
        ids.append(response.json()["id"])
    return ids
